"""``smarts replay info|show|suite``: look at a recording before driving in it, and turn a folder
of recordings into a benchmark suite.

Options are validated by one schema (``smarts.core.schema``), as every other command line's are:
a non-finite, zero or oversized value is refused with the flag named, before any file is read.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError

from smarts import exit_codes
from smarts.command_line import HelpFormatter
from smarts.core.errors import MapError, ReplayError, ScenarioError
from smarts.core.schema import Schema, locate
from smarts.core.spec.replay import COORDINATES, MAX_COORDINATE, REACTIVE_MODES, REPLAY_FORMATS

MAX_WIDTH = 4096
"""Pixels: the widest picture ``show`` draws."""
MAX_FPS = 120.0
MAX_VIDEO_FRAMES = 20_000
"""Frames one video may have (a 9 s Waymo scenario at 10 fps is 91; an NGSIM period at 10 fps 9,000)."""
MAX_SECONDS = 1.0e7

Seconds = Annotated[float, Field(ge=0, le=MAX_SECONDS, allow_inf_nan=False)]
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE, le=MAX_COORDINATE, allow_inf_nan=False)]


class RecordingOptions(Schema):
    """Options every ``replay`` command reads a recording with."""

    offset: Annotated[list[Coordinate], Field(min_length=2, max_length=2)] = Field(
        default_factory=lambda: [0.0, 0.0], description="metres added to x and y last"
    )


class ShowOptions(RecordingOptions):
    """``replay show``'s picture and video settings."""

    time: Seconds | None = Field(None, description=".png: seconds after the first frame")
    start: Seconds = Field(0.0, description="videos: first second shown")
    duration: Annotated[float, Field(gt=0, le=MAX_SECONDS, allow_inf_nan=False)] | None = Field(
        None, description="videos: seconds shown"
    )
    fps: Annotated[float, Field(gt=0, le=MAX_FPS, allow_inf_nan=False)] = Field(10.0, description="frames per second")
    width: Annotated[int, Field(ge=16, le=MAX_WIDTH)] = Field(800, description="picture width in pixels")


def check_options(model: type[Schema], args: argparse.Namespace) -> Schema:
    """The command line's values validated by ``model``; a ``ReplayError`` naming each bad flag."""
    values = {name: getattr(args, name) for name in model.model_fields if hasattr(args, name)}
    if "offset" in values:
        values["offset"] = [float(v) for v in values["offset"]]
    try:
        return model.model_validate(values)
    except ValidationError as exc:
        lines = []
        for problem in exc.errors():
            where, message = locate(model, problem)
            flag = "--" + where.split("[")[0].replace("_", "-")
            lines.append(f"{flag}{where[len(where.split('[')[0]) :]}: {message}")
        raise ReplayError("\n".join(lines)) from None


def add_replay_commands(replay: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """``smarts replay info|show|suite`` (the group is listed in ``smarts.__main__``)."""
    sub = replay.add_subparsers(dest="replay_command", metavar="COMMAND")
    sub.required = True
    p = sub.add_parser("info", help="road users, duration, frames, extent and map of a recording",
                       formatter_class=HelpFormatter)  # fmt: skip
    _recording_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(run=_info)
    p = sub.add_parser("show", help="render a recording to an image (.png) or video (.gif, .mp4)",
                       formatter_class=HelpFormatter)  # fmt: skip
    _recording_args(p)
    p.add_argument("--out", type=Path, required=True, help="output .png, .gif or .mp4 file")
    p.add_argument("--map", type=Path, default=None, help="map (.net.xml, .xodr) drawn under the road users")
    p.add_argument("--time", type=float, default=None, help=".png: seconds after the first frame (default: the middle)")
    p.add_argument("--start", type=float, default=0.0, help="videos: first second shown")
    p.add_argument("--duration", type=float, default=None, help="videos: seconds shown (default: to the end)")
    p.add_argument("--fps", type=float, default=10.0, help=f"videos: frames per second (at most {MAX_FPS:g})")
    p.add_argument("--width", type=int, default=800, help=f"image width in pixels (16 to {MAX_WIDTH})")
    p.add_argument("--follow", default=None, metavar="ID",
                   help="a road user to follow with a fixed-scale camera (6 px/m): its recorded id or ego; none: the "
                        "whole recording (default: videos of a recording with an ego follow it, the rest show all)")  # fmt: skip
    p.set_defaults(run=_show)
    p = sub.add_parser(
        "suite", help="turn a folder of recordings into a benchmark suite of take-over scenarios",
        description="Each scenario file in DIR becomes a scenario in which an agent takes over the recorded ego "
        "(Waymo's self-driving car, Argoverse 2's AV) or --vehicle and drives to where it ended, among the other "
        "recorded road users. Run it with: python -m train benchmark --suite OUT --agent ...",
        formatter_class=HelpFormatter,
    )  # fmt: skip
    p.add_argument("folder", type=Path, help="folder of NGSIM files, Waymo TFRecords or Argoverse 2 scenario folders")
    p.add_argument("--format", required=True, choices=REPLAY_FORMATS, help="dataset format")
    p.add_argument("--out", type=Path, required=True, help="suite YAML to write (paths in it are relative to it)")
    p.add_argument("--map", type=Path, default=None, help="NGSIM: the map (.net.xml, .xodr) the recordings run on")
    p.add_argument("--vehicle", action="append", default=None,
                   help="recorded id to take over (repeatable; default: the recording's ego, or NGSIM's longest "
                        "vehicle that starts and ends on the map)")  # fmt: skip
    p.add_argument("--reactive", choices=REACTIVE_MODES, default="off", help="recorded road users near the agent "
                   "switch to the traffic model (interaction) or all do (always)")  # fmt: skip
    p.add_argument("--name", default=None, help="suite name (default: the --out file's stem)")
    p.add_argument("--coordinates", choices=COORDINATES, default="local", help="NGSIM: which column pair")
    p.add_argument("--swap-xy", action="store_true", help="swap the dataset's x and y")
    p.add_argument("--flip-y", action="store_true", help="negate y (after swapping)")
    p.add_argument("--offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"), help="metres added last")
    p.set_defaults(run=_suite)


def _recording_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="NGSIM CSV/.txt, Argoverse 2 scenario folder or Waymo TFRecord")
    p.add_argument("--format", required=True, choices=REPLAY_FORMATS, help="dataset format")
    p.add_argument("--coordinates", choices=COORDINATES, default="local", help="NGSIM: which column pair")
    p.add_argument("--swap-xy", action="store_true", help="swap the dataset's x and y")
    p.add_argument("--flip-y", action="store_true", help="negate y (after swapping)")
    p.add_argument("--offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"), help="metres added last")
    p.add_argument("--scenario", "--location", dest="scenario", default=None,
                   help="Waymo: scenario id or record index (default: the first); NGSIM: the site (Location column) "
                        "of the data portal's file")  # fmt: skip


def _read(args: argparse.Namespace):
    from smarts.replay.load import read_recording

    return read_recording(
        args.format, args.path, coordinates=args.coordinates, swap_xy=args.swap_xy, flip_y=args.flip_y,
        offset=tuple(args.offset), scenario=args.scenario,
    )  # fmt: skip


def summary(rec) -> dict:
    """What ``info`` prints: counts, times and extent of a recording."""
    from smarts.replay.load import most_at_once
    from smarts.replay.recording import ObjectKind

    types = {ObjectKind(int(t)).name.lower(): int(n) for t, n in zip(*np.unique(rec.kind, return_counts=True))}
    xmin, ymin, xmax, ymax = rec.extent()
    out = {
        "path": rec.source,
        "format": rec.format,
        "vehicles": rec.num_vehicles,
        "duration_s": round(rec.duration, 6),
        "frames": rec.frames,
        "frame_s": rec.dt,
        "samples": int(rec.count.sum()),
        "extent": {"xmin": xmin, "ymin": ymin, "xmax": xmax, "ymax": ymax},
        "types": types,
        "max_at_once": most_at_once(rec),
    }
    if rec.times is not None and len(rec.times) > 1:
        steps = np.diff(rec.times)
        out["frame_s_range"] = [round(float(steps.min()), 6), round(float(steps.max()), 6)]
    if rec.ego is not None:
        out["ego"] = rec.ego
    if rec.road_map is not None:
        dm = rec.road_map
        out["map_lanes"] = len(dm.lane_ids)
        from smarts.replay.recording import MARK_NAMES

        marks = {
            MARK_NAMES[k]: int(n) for k, n in zip(*np.unique(np.asarray(dm.mark_kinds, dtype=int), return_counts=True))
        }
        if marks:
            out["map_marks"] = marks
        if dm.signal_lanes:
            out["signals"] = len(dm.signal_lanes)
    return out


def _fail(err: Exception) -> int:
    """A refused recording, map or option: one ``error:`` line, the input exit code of every command."""
    print(f"error: {err}", file=sys.stderr)
    return exit_codes.BAD_INPUT


def _info(args: argparse.Namespace) -> int:
    try:
        check_options(RecordingOptions, args)
        info = summary(_read(args))
    except ReplayError as err:
        return _fail(err)
    if args.json:
        print(json.dumps(info))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{info['format']} recording {info['path']}", show_header=False)
    e = info["extent"]
    frames = f"{info['frames']} ({info['frame_s']:g} s each"
    if "frame_s_range" in info:
        lo, hi = info["frame_s_range"]
        frames += f"; recorded {lo:g} .. {hi:g} s apart"
    rows = [
        ("vehicles", str(info["vehicles"])),
        ("most at once", str(info["max_at_once"])),
        ("duration", f"{info['duration_s']:.1f} s"),
        ("frames", frames + ")"),
        ("samples", str(info["samples"])),
        ("extent", f"x {e['xmin']:.1f} .. {e['xmax']:.1f} m, y {e['ymin']:.1f} .. {e['ymax']:.1f} m"),
        ("types", ", ".join(f"{k} {v}" for k, v in info["types"].items())),
    ]
    if "ego" in info:
        rows.append(("ego", info["ego"]))
    if "map_lanes" in info:
        rows.append(("map lanes", str(info["map_lanes"])))
    if "map_marks" in info:
        rows.append(("map marks", ", ".join(f"{k} {v}" for k, v in info["map_marks"].items())))
    if "signals" in info:
        rows.append(("signals", str(info["signals"])))
    for key, value in rows:
        table.add_row(key, value)
    Console(width=None if sys.stdout.isatty() else 200, highlight=False).print(table)
    return 0


def _show(args: argparse.Namespace) -> int:
    from smarts.replay.render import render

    try:
        options = check_options(ShowOptions, args)
        rec = _read(args)
        road_map = None
        if args.map is not None:
            from smarts.maps import load_map

            road_map = load_map(args.map)
        follow = "auto" if args.follow is None else None if args.follow == "none" else args.follow
        n = render(rec, args.out, road_map=road_map, time=options.time, fps=options.fps, width=options.width,
                   start=options.start, duration=options.duration, max_frames=MAX_VIDEO_FRAMES, follow=follow)  # fmt: skip
    except (ReplayError, MapError) as err:
        return _fail(err)
    print(f"wrote {args.out} ({n} frame{'s' if n != 1 else ''})")
    return 0


def _suite(args: argparse.Namespace) -> int:
    from smarts.replay.suite import build_suite

    try:
        check_options(RecordingOptions, args)
        written, skipped = build_suite(
            args.folder, args.format, args.out, map_path=args.map, vehicles=args.vehicle, reactive=args.reactive,
            name=args.name, coordinates=args.coordinates, swap_xy=args.swap_xy, flip_y=args.flip_y,
            offset=tuple(args.offset),
        )  # fmt: skip
    except (ReplayError, MapError, ScenarioError) as err:
        return _fail(err)
    for line in skipped:
        print(f"skipped {line}", file=sys.stderr)
    print(f"wrote {args.out} ({written} scenario{'s' if written != 1 else ''}); run it with: python -m train "
          f"benchmark --suite {args.out} --agent <locator>")  # fmt: skip
    return 0
