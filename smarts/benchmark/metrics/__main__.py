"""Score episode logs from a shell: ``python -m smarts.benchmark.metrics LOGS... [--config FILE]``."""

from __future__ import annotations

import argparse
import json
import sys

from smarts.benchmark.metrics.log import read_episodes
from smarts.benchmark.metrics.params import load_params
from smarts.benchmark.metrics.scores import score_suite
from smarts.core.errors import LogError, MetricParamsError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m smarts.benchmark.metrics",
        description="Score benchmark episode logs (.npz files, or folders searched recursively).",
    )
    parser.add_argument(
        "paths", nargs="+", help="episode .npz files and/or folders holding them"
    )
    parser.add_argument(
        "--config", help="metrics YAML (default: configs/benchmark/metrics.yaml)"
    )
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
            raise ValueError(
                f"no .npz episode logs found under {', '.join(args.paths)}"
            )
        scores = score_suite(logs, params)
    except (LogError, MetricParamsError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(scores.to_dict(), indent=2) if args.json else scores.format_table()
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
