"""``python -m train <command>``: train PPO, evaluate checkpoints, run the benchmark.

python -m train ppo --task platoon [--action-space rtp|continuous] [--total-steps N] [--envs E]
python -m train ppo --task platoon --lib sb3 --resume runs/train/platoon/last.pt
python -m train eval --agent runs/train/platoon/latest --suite adaptive     (a run folder: its best.pt)
python -m train benchmark --agent zoo:keep-lane --agent zoo:random --suite collaborative
    (each run in a new folder runs/benchmark/<suite>/001, 002, ...; latest -> the newest)
python -m train enjoy --agent zoo:keep-lane --scenario adaptive:a01_straight_free --video out.mp4 [--viz]
add --ray-address auto|local|HOST:PORT to run episodes (benchmark, eval) or collectors (ppo) on Ray
python -m train trajectories | aid-predictor | tf-bc | vcr-classifier   (the planners' learned parts)
"""

from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path

from smarts import exit_codes
from smarts.command_line import Command, HelpFormatter, add_commands


def _benchmark(args: argparse.Namespace) -> int:
    from smarts.worker_processes import start_worker_server

    if (args.workers > 1 or args.episode_timeout is not None) and not args.ray_address:
        # It imports what workers need while this process loads the agents; not torch: the reference
        # agents, most of the episodes, need none, and a worker whose policy is a network imports it.
        # And pyplot, for the figure helpers forked from it: they can draw as soon as they start.
        start_worker_server(torch=False, also=("smarts.benchmark.figure_preload",))
    from smarts.benchmark.agents import REFERENCE_AGENTS, agent_locator
    from smarts.benchmark.jobs import benchmark_folder, claim_folder, plan_jobs
    from smarts.benchmark.report import FigureHelpers, ReportAhead, write_report
    from smarts.benchmark.runner import BenchmarkInterrupted, run_jobs
    from smarts.benchmark.suites import load_suite

    suite = load_suite(args.suite)
    agents = list(dict.fromkeys(agent_locator(a) for a in args.agent or []))  # a run folder: its best.pt
    episodes = args.episodes or suite.episodes
    # A new numbered folder per run (runs/benchmark/<suite>/001, ...; latest -> the newest), or
    # --out, never over another run; --resume finishes the latest (or --out).
    out, numbered = benchmark_folder(suite.name, args.out, args.resume)
    # Loads every agent and checks the suite hosts its action space before any episode runs.
    jobs = plan_jobs(agents, suite, episodes, out, args.seed)
    claimed = claim_folder(out, numbered)
    if claimed != out:  # another run took that number meanwhile
        out, jobs = claimed, plan_jobs(agents, suite, episodes, claimed, args.seed)
    shown = agents + [a for a in REFERENCE_AGENTS if a not in agents]
    print(f"{suite.name}: {len(suite.scenarios)} scenarios x {episodes} episodes x {len(shown)} agent(s) "
          f"({', '.join(shown)}; references always included) -> {out}")  # fmt: skip
    helpers = FigureHelpers.for_figures(len(suite.scenarios))  # they load matplotlib while episodes run
    # Reads the logs and hands the helpers trajectory figures as the episodes finish.
    ahead = ReportAhead(out, suite, agents, jobs, helpers)
    try:
        results = run_jobs(jobs, workers=args.workers, progress=not args.quiet, ray_address=args.ray_address,
                           resume=args.resume, episode_timeout=args.episode_timeout,
                           batch=not args.per_episode, on_result=ahead.offer)  # fmt: skip
    except BenchmarkInterrupted as stop:  # Ctrl-C: report what finished, no traceback
        helpers.close()  # Ctrl-C reached them too
        ahead.cancel()
        write_report(out, suite, agents, stop.finished, not_run=stop.not_run, ahead=ahead)
        print(f"interrupted: {len(stop.finished)} of {len(jobs)} episodes finished, reported in {out}; "
              f"the same command with --resume{'' if numbered else f' --out {out}'} runs the rest",
              file=sys.stderr)  # fmt: skip
        return exit_codes.INTERRUPTED
    except BaseException:
        helpers.close()
        ahead.cancel()
        raise
    report = write_report(out, suite, agents, results, helpers=helpers, ahead=ahead)
    print(report.read_text())
    failed = [r for r in results if r.get("failure")]
    if failed:
        print(f"{len(failed)} episode(s) failed; reasons are in {out / 'results.json'}", file=sys.stderr)
    print(f"report: {report}", file=sys.stderr)
    return exit_codes.OK


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


def _benchmark_options(parser: argparse.ArgumentParser, agent_required: bool = False) -> None:
    """The options of ``benchmark`` and ``eval`` (which must name its agents: evaluating only the
    reference rows is never what ``eval`` means)."""
    parser.add_argument("--agent", action="append", required=agent_required,
                        help="agent: a zoo: locator, a checkpoint (.pt) or a training run folder (its best.pt, e.g. "
                             "runs/train/platoon/latest); repeatable. The reference agents zoo:keep-lane, zoo:random "
                             "and zoo:stand-still are always benchmarked beside them")  # fmt: skip
    parser.add_argument("--suite", default="collaborative", help="collaborative | adaptive | path to a suite YAML")
    parser.add_argument("--episodes", type=int, default=None, help="episodes per scenario (default: the suite's)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes")
    parser.add_argument("--seed", type=int, default=None, help="first episode seed (default: the suite's)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder, which must not hold another run (default: the next numbered folder "
                             "runs/benchmark/<suite>/001, 002, ...; runs/benchmark/<suite>/latest points to it)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--ray-address", default=None,
                        help="run episodes as Ray tasks: auto | local | HOST:PORT (needs the ray extra)")  # fmt: skip
    parser.add_argument("--episode-timeout", type=float, default=None,
                        help="seconds an episode may run before its worker is killed and the episode recorded as "
                             "failed (default: no limit; not with --ray-address)")  # fmt: skip
    parser.add_argument("--resume", action="store_true",
                        help="finish an interrupted run: the suite's latest run (or --out); episodes whose logs are "
                             "there and valid are not run again")  # fmt: skip
    parser.add_argument("--per-episode", action="store_true",
                        help="one env per episode instead of a few simulations of many episodes each (the same "
                             "logs and numbers, several times slower; for comparison)")  # fmt: skip
    parser.set_defaults(run=_benchmark)


def _ppo_parser(ppo: argparse.ArgumentParser, argv: list[str] | None) -> None:
    ppo.epilog = PPO_EPILOG
    from train.config import CONFIG_DIR

    shipped = ", ".join(sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")))
    ppo.add_argument(
        "--config",
        default=None,
        help=f"a training config YAML (or a run's config.json) instead of the task's; a bare name is a shipped one "
        f"({shipped}: configs/train/<name>.yaml)",
    )
    ppo.add_argument("--quiet", action="store_true", help="no progress bar")
    ppo.add_argument("--resume", default=None,
                     help="continue a run from one of its .pt checkpoints (e.g. runs/train/platoon/last.pt), "
                          "either library")  # fmt: skip
    _ppo_options(ppo, argv)
    ppo.set_defaults(run=_ppo)


COMMANDS = (
    Command("benchmark", "run agents through a benchmark suite and write a report",
            lambda parser, argv: _benchmark_options(parser)),
    Command("eval", "benchmark checkpoints or zoo agents on a suite (benchmark with --agent required)",
            lambda parser, argv: _benchmark_options(parser, agent_required=True)),
    Command("ppo", "train a PPO driving policy (torchrl collectors, GAE, ClipPPOLoss)", _ppo_parser),
    Command("trajectories", "log every vehicle's track in the suites' scenarios (data sets)",
            "train.trajectories:add_options"),
    Command("aid-predictor", "train AID's motion predictor on logged trajectories", "train.aid_predictor:add_options"),
    Command("tf-bc", "behaviour-clone TF's stop/move network (keep-lane demonstrations, hindsight stops)",
            "train.tf_bc:add_options"),
    Command("vcr-classifier", "generate VCR's exploration data and train its event classifier",
            "train.vcr_classifier:add_options"),
    Command("enjoy", "watch a policy drive a scenario (browser, video or TensorBoard)", "train.enjoy:add_options"),
)  # fmt: skip
"""The commands, in the order ``--help`` lists them; a command's module is imported only when it is
the one named (see ``smarts.command_line``)."""


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``argv``'s command (and the list of every command); ``argv`` None: a parser
    with every command's options."""
    summary, _, examples = __doc__.partition("\n\n")
    summary = summary.split(": ", 1)[-1]  # the docstring's first line without its markup
    parser = argparse.ArgumentParser(prog="python -m train", description=summary[:1].upper() + summary[1:],
                                     epilog=f"examples:\n{examples.rstrip()}", formatter_class=HelpFormatter)  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_commands(sub, COMMANDS, argv)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
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
        return exit_codes.BAD_INPUT
    except KeyboardInterrupt:  # what was saved has been said already; no traceback
        print("interrupted", file=sys.stderr)
        return exit_codes.INTERRUPTED
    except OSError as err:  # a disk that fills up or a folder that stops taking files mid-run
        if err.errno not in WRITE_ERRORS:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"error: {where}{err.strerror or err} (the files written before it are kept)", file=sys.stderr)
        return exit_codes.FAILED


WRITE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)
"""Errors of writing that a user fixes (free space, permissions), reported without a traceback."""


def exit_without_teardown(code: int | None) -> None:
    """End the process once a command is done: the exit handlers run (worker pools, TensorBoard
    writers, logging) and the standard streams are flushed, but the interpreter is not torn down
    module by module. The commands' files are closed by then; the teardown only unloads the
    libraries, and torch's alone takes about half a second of every command."""
    import atexit
    import os

    if sys.getprofile() is not None or sys.gettrace() is not None:
        raise SystemExit(code)  # under a profiler or coverage, which write their results on the way out
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (| head): nothing more can be said there
            pass
    os._exit(code or 0)


if __name__ == "__main__":
    exit_without_teardown(main())
