"""The ``smarts`` command line (also ``python -m smarts``)."""

from __future__ import annotations

import argparse
import sys

from smarts import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="smarts", description="A fast, PyTorch-native driving simulator."
    )
    parser.add_argument("--version", action="version", version=f"smarts {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    from smarts.scenario.cli import add_commands as add_scenario_commands

    add_scenario_commands(subparsers)
    from smarts.viz.cli import add_commands as add_viz_commands

    add_viz_commands(subparsers)
    from smarts.replay.cli import add_commands as add_replay_commands

    add_replay_commands(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    run = getattr(args, "run", None)
    if run is None:
        parser.print_help()
        return 2
    return int(run(args))


if __name__ == "__main__":
    sys.exit(main())
