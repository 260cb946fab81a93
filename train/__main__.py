"""``python -m train <command>``: benchmark (and, as they land, training and evaluation).

    python -m train benchmark --agent zoo:keep-lane --agent zoo:random --suite collaborative
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _benchmark(args: argparse.Namespace) -> int:
    from smarts.benchmark.report import write_report
    from smarts.benchmark.runner import REFERENCE_AGENTS, load_policy, plan_jobs, run_jobs
    from smarts.benchmark.suites import load_suite

    suite = load_suite(args.suite)
    agents = args.agent or list(REFERENCE_AGENTS)
    for agent in agents:
        load_policy(agent)  # an unknown locator is an error now, not a failure per episode
    episodes = args.episodes or suite.episodes
    out = args.out or Path("runs") / "benchmark" / suite.name
    jobs = plan_jobs(agents, suite, episodes, out, args.seed)
    print(f"{suite.name}: {len(suite.scenarios)} scenarios x {episodes} episodes x {len(agents)} agent(s) -> {out}")
    results = run_jobs(jobs, workers=args.workers, progress=not args.quiet)
    report = write_report(out, suite, agents, results)
    print(report.read_text())
    failed = [r for r in results if r.get("failure")]
    if failed:
        print(f"{len(failed)} episode(s) failed; reasons are in {out / 'results.json'}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m train", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    bench = sub.add_parser("benchmark", help="run agents through a benchmark suite and write a report")
    bench.add_argument("--agent", action="append", help="agent locator (repeatable); default: the reference agents")
    bench.add_argument("--suite", default="collaborative", help="collaborative | adaptive | path to a suite YAML")
    bench.add_argument("--episodes", type=int, default=None, help="episodes per scenario (default: the suite's)")
    bench.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    bench.add_argument("--seed", type=int, default=None, help="first episode seed (default: the suite's)")
    bench.add_argument("--out", type=Path, default=None, help="output folder (default runs/benchmark/<suite>)")
    bench.add_argument("--quiet", action="store_true", help="no progress bar")
    bench.set_defaults(run=_benchmark)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "episodes", None) is not None and args.episodes < 1:
        build_parser().error("--episodes must be >= 1")
    if getattr(args, "workers", 1) < 1:
        build_parser().error("--workers must be >= 1")
    try:
        return args.run(args)
    except ValueError as err:  # unknown suite, agent or malformed config: say it plainly
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
