"""``python -m train <command>``: train PPO, evaluate checkpoints, run the benchmark.

    python -m train ppo --task platoon [--action-space rtp|continuous] [--total-steps N] [--envs E]
    python -m train ppo --task platoon --lib sb3 --resume runs/train/platoon/last.pt
    python -m train eval --agent runs/train/platoon/final.pt --suite adaptive
    python -m train benchmark --agent zoo:keep-lane --agent zoo:random --suite collaborative
    python -m train enjoy --agent zoo:keep-lane --scenario adaptive:a01_straight_free --video out.mp4 [--viz]
    add --ray-address auto|local|HOST:PORT to run episodes (benchmark, eval) or collectors (ppo) on Ray
    python -m train trajectories | aid-predictor | tf-bc | vcr-classifier   (the planners' learned parts)
"""

from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path


def _benchmark(args: argparse.Namespace) -> int:
    from smarts.benchmark.report import write_report
    from smarts.benchmark.runner import REFERENCE_AGENTS, BenchmarkInterrupted, plan_jobs, run_jobs
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
    try:
        results = run_jobs(jobs, workers=args.workers, progress=not args.quiet, ray_address=args.ray_address,
                           resume=args.resume, episode_timeout=args.episode_timeout)  # fmt: skip
    except BenchmarkInterrupted as stop:  # Ctrl-C: report what finished, no traceback
        write_report(out, suite, agents, stop.finished, not_run=stop.not_run)
        print(f"interrupted: {len(stop.finished)} of {len(jobs)} episodes finished, reported in {out}; "
              "the same command with --resume runs the rest", file=sys.stderr)  # fmt: skip
        return 130
    report = write_report(out, suite, agents, results)
    print(report.read_text())
    failed = [r for r in results if r.get("failure")]
    if failed:
        print(f"{len(failed)} episode(s) failed; reasons are in {out / 'results.json'}", file=sys.stderr)
    return 0


def _ppo(args: argparse.Namespace) -> int:
    from train.config import TrainConfig, load_config

    overrides = {name: getattr(args, name) for name in TrainConfig.model_fields if name != "task"}
    cfg = load_config(args.task, args.config, {k: v for k, v in overrides.items() if v is not None})
    from train.run import check_run_folder, run_folder

    resume = Path(args.resume) if args.resume else None
    out = run_folder(cfg, resume)
    check_run_folder(out)  # fail fast, before the trainer and its envs are built
    cfg = cfg.model_copy(update={"out": str(out)})
    if cfg.lib == "sb3":
        from train.sb3_ppo import train_sb3

        final = train_sb3(cfg, out, progress=not args.quiet, resume=resume)
    else:
        from train.ppo import train

        final = train(cfg, out, progress=not args.quiet, resume=resume)
    print(f"checkpoint: {final}\nTensorBoard: tensorboard --logdir {out / 'tensorboard'}")
    return 0


PPO_EPILOG = """Every setting of the training config is an option; the defaults shown are the task's
configs/train/<task>.yaml (or --config FILE), else the schema's. Values are YAML: --hidden 256,256
or --hidden "[256, 256]", --reward "{follow: 2}", --interface "{lead: true}", --eval-suite null; a
list starting with a minus sign goes as --init-log-std=-1.2,-0.7 or "[-1.2, -0.7]"."""


def _ppo_options(ppo: argparse.ArgumentParser, argv: list[str] | None) -> None:
    """``--field-name`` for every field of the training config, its help showing the field's type and
    its default in the YAML that ``--task``/``--config`` in ``argv`` select."""
    from smarts.core.schema import cli_options
    from train.config import TrainConfig, flag, task_defaults

    argv = [str(a) for a in (sys.argv[1:] if argv is None else argv)]
    values, file = task_defaults(_given(argv, "--task") or "platoon", _given(argv, "--config"))
    for name, default, text in cli_options(TrainConfig):
        if name in values:
            text = text.replace(f"default: {default!r})", f"default: {values[name]!r} in {file})")
        if name == "task":  # it picks the YAML of the defaults (with --config, the task the file may omit)
            text = f"{text[:-1]}; it selects configs/train/<task>.yaml, the defaults of the options below)"
            ppo.add_argument("--task", default="platoon", metavar="TASK", help=text)
            continue
        names = [flag(name), "--out"] if name == "out" else [flag(name)]
        metavar = flag(name)[2:].upper().replace("-", "_")
        ppo.add_argument(*names, dest=name, default=None, metavar=metavar, help=text.replace("%", "%%"))


def _given(argv: list[str], option: str) -> str | None:
    """The value of ``option`` in ``argv`` (``--option value`` or ``--option=value``), if any."""
    for i, arg in enumerate(argv):
        if arg == option and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(option + "="):
            return arg.split("=", 1)[1]
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
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
    bench.add_argument("--episode-timeout", type=float, default=None,
                       help="seconds an episode may run before its worker is killed and the episode recorded as "
                            "failed (default: no limit; not with --ray-address)")  # fmt: skip
    bench.add_argument("--resume", action="store_true",
                       help="finish an interrupted run in --out: episodes whose logs are there and valid are "
                            "not run again")  # fmt: skip
    bench.set_defaults(run=_benchmark)

    evaluate = sub.add_parser("eval", help="benchmark a checkpoint or zoo agent on a suite (same as benchmark)")
    for action in bench._actions[1:]:
        evaluate._add_action(action)
    evaluate.set_defaults(run=_benchmark)

    ppo = sub.add_parser("ppo", help="train a PPO driving policy (torchrl collectors, GAE, ClipPPOLoss)",
                         epilog=PPO_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ppo.add_argument("--config", default=None, help="a training config YAML (or a run's config.json) instead of the task's")
    ppo.add_argument("--quiet", action="store_true", help="no progress bar")
    ppo.add_argument("--resume", default=None,
                     help="continue a run from one of its .pt checkpoints (e.g. runs/train/platoon/last.pt), "
                          "either library")  # fmt: skip
    _ppo_options(ppo, argv)
    ppo.set_defaults(run=_ppo)

    from train import aid_predictor, tf_bc, trajectories, vcr_classifier

    trajectories.add_parser(sub)
    aid_predictor.add_parser(sub)
    tf_bc.add_parser(sub)
    vcr_classifier.add_parser(sub)

    from train.enjoy import add_parser as add_enjoy

    add_enjoy(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if args.command in ("benchmark", "eval"):
        if args.episodes is not None and args.episodes < 1:
            parser.error("--episodes must be >= 1")
        if args.workers < 1:
            parser.error("--workers must be >= 1")
        timeout = getattr(args, "episode_timeout", None)
        if timeout is not None and not timeout > 0:
            parser.error("--episode-timeout must be a positive number of seconds")
        if timeout is not None and getattr(args, "ray_address", None):
            parser.error("--episode-timeout does not apply to Ray tasks (--ray-address)")
    try:
        return args.run(args)
    except ValueError as err:  # unknown suite, agent or malformed config: say it plainly
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # what was saved has been said already; no traceback
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as err:  # a disk that fills up or a folder that stops taking files mid-run
        if err.errno not in WRITE_ERRORS:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"error: {where}{err.strerror or err} (the files written before it are kept)", file=sys.stderr)
        return 1


WRITE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)
"""Errors of writing that a user fixes (free space, permissions), reported without a traceback."""


if __name__ == "__main__":
    raise SystemExit(main())
