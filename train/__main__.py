"""``python -m train <command>``: train PPO, evaluate checkpoints, run the benchmark.

    python -m train ppo --task platoon [--action-space rtp|continuous] [--total-steps N] [--envs E]
    python -m train ppo --task platoon --lib sb3 --resume runs/train/platoon/last.pt
    python -m train eval --agent runs/train/platoon/final.pt --suite adaptive
    python -m train benchmark --agent zoo:keep-lane --agent zoo:random --suite collaborative
    add --ray-address auto|local|HOST:PORT to run episodes (benchmark, eval) or collectors (ppo) on Ray
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path


def _benchmark(args: argparse.Namespace) -> int:
    from smarts.benchmark.report import write_report
    from smarts.benchmark.runner import REFERENCE_AGENTS, plan_jobs, run_jobs
    from smarts.benchmark.suites import load_suite

    suite = load_suite(args.suite)
    agents = list(dict.fromkeys(args.agent or []))
    episodes = args.episodes or suite.episodes
    out = args.out or Path("runs") / "benchmark" / suite.name
    # Loads every agent and checks the suite hosts its action space before any episode runs.
    jobs = plan_jobs(agents, suite, episodes, out, args.seed)
    shown = agents + [a for a in REFERENCE_AGENTS if a not in agents]
    print(f"{suite.name}: {len(suite.scenarios)} scenarios x {episodes} episodes x {len(shown)} agent(s) "
          f"({', '.join(shown)}; references always included) -> {out}")  # fmt: skip
    results = run_jobs(jobs, workers=args.workers, progress=not args.quiet, ray_address=args.ray_address)
    report = write_report(out, suite, agents, results)
    print(report.read_text())
    failed = [r for r in results if r.get("failure")]
    if failed:
        print(f"{len(failed)} episode(s) failed; reasons are in {out / 'results.json'}", file=sys.stderr)
    return 0


def _ppo(args: argparse.Namespace) -> int:
    from train.config import TrainConfig, load_config

    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainConfig) if getattr(args, f.name, None) is not None}
    overrides.pop("task", None)
    cfg = load_config(args.task, args.config, overrides)
    out = Path(args.out_dir) if args.out_dir else Path(cfg.out)
    resume = Path(args.resume) if args.resume else None
    if cfg.lib == "sb3":
        from train.sb3_ppo import train_sb3

        final = train_sb3(cfg, out, progress=not args.quiet, resume=resume)
    else:
        from train.ppo import train

        final = train(cfg, out, progress=not args.quiet, resume=resume)
    print(f"checkpoint: {final}\nTensorBoard: tensorboard --logdir {out / 'tensorboard'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m train", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("benchmark", help="run agents through a benchmark suite and write a report")
    bench.add_argument("--agent", action="append",
                       help="agent locator or checkpoint (repeatable); the reference agents zoo:keep-lane, "
                            "zoo:random and zoo:stand-still are always benchmarked beside them")  # fmt: skip
    bench.add_argument("--suite", default="collaborative", help="collaborative | adaptive | path to a suite YAML")
    bench.add_argument("--episodes", type=int, default=None, help="episodes per scenario (default: the suite's)")
    bench.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    bench.add_argument("--seed", type=int, default=None, help="first episode seed (default: the suite's)")
    bench.add_argument("--out", type=Path, default=None, help="output folder (default runs/benchmark/<suite>)")
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.add_argument("--ray-address", default=None,
                       help="run episodes as Ray tasks: auto | local | HOST:PORT (needs the ray extra)")  # fmt: skip
    bench.set_defaults(run=_benchmark)

    evaluate = sub.add_parser("eval", help="benchmark a checkpoint or zoo agent on a suite (same as benchmark)")
    for action in bench._actions[1:]:
        evaluate._add_action(action)
    evaluate.set_defaults(run=_benchmark)

    from train.config import TrainConfig

    ppo = sub.add_parser("ppo", help="train a PPO driving policy (torchrl collectors, GAE, ClipPPOLoss)")
    ppo.add_argument("--task", default="platoon", help="platoon | drive (defaults in configs/train/<task>.yaml)")
    ppo.add_argument("--config", default=None, help="a training config YAML instead of the task's")
    ppo.add_argument("--out-dir", default=None,
                     help="run folder (default: the config's out); one that holds another run is refused")  # fmt: skip
    ppo.add_argument("--quiet", action="store_true", help="no progress bar")
    ppo.add_argument("--resume", default=None,
                     help="continue a run from one of its .pt checkpoints (e.g. runs/train/platoon/last.pt), "
                          "either library")  # fmt: skip
    for f in dataclasses.fields(TrainConfig):
        if f.name in ("task", "out"):
            continue
        ppo.add_argument("--" + f.name.replace("_", "-"), dest=f.name, default=None, help=f"override {f.name}")
    ppo.set_defaults(run=_ppo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command in ("benchmark", "eval"):
        if args.episodes is not None and args.episodes < 1:
            build_parser().error("--episodes must be >= 1")
        if args.workers < 1:
            build_parser().error("--workers must be >= 1")
    try:
        return args.run(args)
    except ValueError as err:  # unknown suite, agent or malformed config: say it plainly
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
