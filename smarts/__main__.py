"""The ``smarts`` command line (also ``python -m smarts``)."""

from __future__ import annotations

import argparse
import sys

from smarts import __version__
from smarts.command_line import Command, HelpFormatter, add_commands

COMMANDS = (
    Command("scenario", "list and inspect scenarios", "smarts.scenario.cli:add_scenario_commands"),
    Command("map", "list and build the built-in maps", "smarts.scenario.cli:add_map_commands"),
    Command("viz", "the diagnostic web viewer (recorded and live episodes)", "smarts.viz.cli:add_viz_command"),
    Command("replay", "inspect and render recorded datasets (NGSIM, Argoverse 2, Waymo)",
            "smarts.replay.cli:add_replay_commands"),
)  # fmt: skip
"""The command groups, in the order ``--help`` lists them; a group's module is imported only when it
is the one named (see ``smarts.command_line``)."""


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser of ``argv``'s command (and the list of every command); ``argv`` None: a parser
    with every command."""
    parser = argparse.ArgumentParser(prog="smarts", description="A fast, PyTorch-native driving simulator.",
                                     formatter_class=HelpFormatter)  # fmt: skip
    parser.add_argument("--version", action="version", version=f"smarts {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    add_commands(subparsers, COMMANDS, argv)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the process exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    run = getattr(args, "run", None)
    if run is None:
        parser.print_help()
        return 2
    return int(run(args))


if __name__ == "__main__":
    sys.exit(main())
