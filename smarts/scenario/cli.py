"""``smarts scenario ...`` and ``smarts map ...`` commands."""

from __future__ import annotations

import argparse
import sys

from rich.console import Console
from rich.table import Table

from smarts import exit_codes
from smarts.command_line import HelpFormatter
from smarts.core.errors import NetconvertError, ScenarioError
from smarts.scenario import scenario_to_yaml
from smarts.scenario.builtin_maps import BUILTIN_MAPS, builtin_map_path
from smarts.scenario.library import list_scenarios, load_scenario


def add_scenario_commands(scenario: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """``smarts scenario list|show|validate`` (the group is listed in ``smarts.__main__``)."""
    scenario_sub = scenario.add_subparsers(dest="scenario_command", metavar="COMMAND")
    scenario_sub.required = True
    p = scenario_sub.add_parser("list", help="list the built-in scenarios", formatter_class=HelpFormatter)
    p.set_defaults(run=_scenario_list)
    p = scenario_sub.add_parser("show", help="print a scenario's validated spec as YAML", formatter_class=HelpFormatter)
    p.add_argument("name", help="built-in scenario name or path to a scenario .yaml file")
    p.add_argument(
        "--build",
        action="store_true",
        help="also build and load its map and make the checks of 'validate' (exit code 2 on a problem, as validate)",
    )
    p.set_defaults(run=_scenario_show)
    p = scenario_sub.add_parser(
        "validate",
        help="check scenario files against their maps: every problem, exit code 2 when any",
        description="Read each scenario, build its map (netconvert where needed) and check every "
        "field, every agent's mission (start on a lane, speed within the lane's limit, goal on the "
        "map, a route from start to goal) and every traffic flow and trip route. Prints one line "
        "per problem naming the file and field; exit code 0 when every scenario is valid, 2 when "
        "any is not.",
        formatter_class=HelpFormatter,
    )
    p.add_argument("files", nargs="+", metavar="FILE", help="scenario .yaml file or built-in scenario name")
    p.set_defaults(run=_scenario_validate)


def add_map_commands(maps: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """``smarts map list|build`` (the group is listed in ``smarts.__main__``)."""
    map_sub = maps.add_subparsers(dest="map_command", metavar="COMMAND")
    map_sub.required = True
    p = map_sub.add_parser("list", help="list the built-in maps", formatter_class=HelpFormatter)
    p.set_defaults(run=_map_list)
    p = map_sub.add_parser(
        "build", help="build a built-in map with netconvert; print its path", formatter_class=HelpFormatter
    )
    p.add_argument("name", help="built-in map name")
    p.set_defaults(run=_map_build)


def _console() -> Console:
    # Piped output (files, tests) gets a wide console so table cells are not cut.
    return Console(width=None if sys.stdout.isatty() else 200, highlight=False)


def _fail(message: str, code: int = exit_codes.BAD_INPUT) -> int:
    """One ``error:`` line on stderr and the exit code of its kind (``smarts.exit_codes``)."""
    print(f"error: {message}", file=sys.stderr)
    return code


def _scenario_list(args: argparse.Namespace) -> int:
    table = Table(title="Built-in scenarios")
    for column in ("name", "map", "agents", "episode steps"):
        table.add_column(column, no_wrap=True)
    for name in list_scenarios():
        spec = load_scenario(name)
        table.add_row(name, spec.map, str(len(spec.agents)), str(spec.episode_steps))
    _console().print(table)
    return 0


def _scenario_show(args: argparse.Namespace) -> int:
    try:
        spec = load_scenario(args.name)
    except ScenarioError as exc:
        return _fail(str(exc))
    sys.stdout.write(scenario_to_yaml(spec))
    if not args.build:
        return 0
    result = _validate(args.name)
    if result.map_file is not None:
        print(f"# map file: {result.map_file}")
    if result.road_map is not None:
        print(f"# {_map_summary(result.road_map)}")
    if not result.valid:
        return _fail("\n".join(result.problems))
    print("# missions and traffic: every road, lane, offset, speed and route checked on the map")
    return 0


def _scenario_validate(args: argparse.Namespace) -> int:
    invalid = 0
    for name in args.files:
        result = _validate(name)
        if result.valid:
            spec = result.spec
            agents = f"{len(spec.agents)} agent{'s' if len(spec.agents) != 1 else ''}"
            print(f"{spec.source}: valid ({agents}; map {spec.map}: {_map_summary(result.road_map)})")
            continue
        invalid += 1
        for line in result.problems:
            print(line)
    if len(args.files) > 1:
        print(f"{len(args.files) - invalid} of {len(args.files)} scenarios valid", file=sys.stderr)
    return exit_codes.BAD_INPUT if invalid else exit_codes.OK


def _validate(name: str):
    """``validate_scenario`` that turns even an unforeseen error into a problem line (no traceback)."""
    from smarts.scenario.validate import Validation, validate_scenario

    try:
        return validate_scenario(name)
    except Exception as exc:  # noqa: BLE001 - a command reports, it does not crash
        return Validation(
            name, [f"{name}: internal error while validating (please report it): {type(exc).__name__}: {exc}"]
        )


def _map_summary(road_map) -> str:
    internal = sum(1 for r in road_map.road_ids if r.startswith(":"))
    return f"roads: {len(road_map.road_ids) - internal} (+{internal} inside junctions), lanes: {road_map.num_lanes}"


def _map_list(args: argparse.Namespace) -> int:
    table = Table(title="Built-in maps")
    table.add_column("name", no_wrap=True)
    table.add_column("description")
    for name in sorted(BUILTIN_MAPS):
        table.add_row(name, BUILTIN_MAPS[name].description)
    _console().print(table)
    return 0


def _map_build(args: argparse.Namespace) -> int:
    try:
        path = builtin_map_path(args.name)
    except ScenarioError as exc:
        return _fail(str(exc))
    except NetconvertError as exc:  # the tool failed on a map of ours: not the user's input
        return _fail(str(exc), exit_codes.FAILED)
    print(path)
    return 0
