"""Score episode logs from a shell: ``python -m smarts.benchmark.metrics LOGS... [--config FILE]``.

A benchmark's ``logs`` folder holds every agent's episodes (``logs/<agent>/<scenario>/episode_000.npz``):
each agent (the ``agent`` recorded in a log's info) is scored on its own, and so is each task when the
logs of both suites are given. With one agent and task the output is that suite's table (``--json``:
its scores); with several, one table per agent and task, each under a heading (``--json``:
``{"agents": [{"agent": ..., "task": ..., "scores": {...}}, ...]}``).
"""

from __future__ import annotations

import argparse
import json
import sys

from smarts.benchmark.metrics.log import EpisodeLog, read_episodes
from smarts.benchmark.metrics.params import load_params
from smarts.benchmark.metrics.scores import score_suite
from smarts.core.errors import LogError, MetricParamsError


def group_logs(logs: list[EpisodeLog]) -> dict[tuple[str | None, str], list[EpisodeLog]]:
    """Logs by (agent, task), in the order first seen: an episode is one agent's run of a scenario,
    so the same scenario and episode index may appear once per agent. Logs that record no agent
    form one group (agent None)."""
    groups: dict[tuple[str | None, str], list[EpisodeLog]] = {}
    for log in logs:
        agent = log.info.get("agent") if isinstance(log.info, dict) else None
        groups.setdefault((agent, log.task), []).append(log)
    return groups


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m smarts.benchmark.metrics",
        description="Score benchmark episode logs (.npz files, or folders searched recursively), "
        "each agent and task on its own.",
    )
    parser.add_argument("paths", nargs="+", help="episode .npz files and/or folders holding them")
    parser.add_argument("--config", help="metrics YAML (default: configs/benchmark/metrics.yaml)")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the scores as JSON instead of a table",
    )
    args = parser.parse_args(argv)
    try:
        params = load_params(args.config)
        logs = read_episodes(args.paths)
        if not logs:
            raise ValueError(f"no .npz episode logs found under {', '.join(args.paths)}")
        scored = [(agent, task, score_suite(group, params)) for (agent, task), group in group_logs(logs).items()]
    except (LogError, MetricParamsError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if len(scored) == 1:
        scores = scored[0][2]
        print(json.dumps(scores.to_dict(), indent=2) if args.json else scores.format_table())
    elif args.json:
        rows = [{"agent": a, "task": t, "scores": s.to_dict()} for a, t, s in scored]
        print(json.dumps({"agents": rows}, indent=2))
    else:
        print(
            "\n\n".join(
                f"agent: {agent if agent is not None else '(not recorded)'}\n{s.format_table()}"
                for agent, _, s in scored
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
