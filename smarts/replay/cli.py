"""``smarts replay info`` and ``smarts replay show``: look at a recording before driving in it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from smarts.core.errors import MapError, ReplayError
from smarts.core.spec.replay import COORDINATES, REPLAY_FORMATS
from smarts.core.vehicle_table import VehicleType
from smarts.replay.load import most_at_once


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register the ``replay`` command group on the top-level parser."""
    replay = subparsers.add_parser("replay", help="inspect and render recorded datasets (NGSIM, Argoverse 2, Waymo)")
    sub = replay.add_subparsers(dest="replay_command", metavar="COMMAND")
    sub.required = True
    p = sub.add_parser("info", help="vehicles, duration, frames and extent of a recording",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    _recording_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(run=_info)
    p = sub.add_parser("show", help="render a recording to an image (.png) or video (.gif, .mp4)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    _recording_args(p)
    p.add_argument("--out", type=Path, required=True, help="output .png, .gif or .mp4 file")
    p.add_argument("--map", type=Path, default=None, help="map (.net.xml, .xodr) drawn under the vehicles")
    p.add_argument("--time", type=float, default=None, help=".png: seconds after the first frame (default: the middle)")
    p.add_argument("--start", type=float, default=0.0, help="videos: first second shown")
    p.add_argument("--duration", type=float, default=None, help="videos: seconds shown (default: to the end)")
    p.add_argument("--fps", type=float, default=10.0, help="videos: frames per second")
    p.add_argument("--width", type=int, default=800, help="image width in pixels")
    p.set_defaults(run=_show)


def _recording_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", type=Path, help="NGSIM CSV, Argoverse 2 scenario folder or Waymo TFRecord")
    p.add_argument("--format", required=True, choices=REPLAY_FORMATS, help="dataset format")
    p.add_argument("--coordinates", choices=COORDINATES, default="local", help="NGSIM: which column pair")
    p.add_argument("--swap-xy", action="store_true", help="swap the dataset's x and y")
    p.add_argument("--flip-y", action="store_true", help="negate y (after swapping)")
    p.add_argument("--offset", type=float, nargs=2, default=(0.0, 0.0), metavar=("X", "Y"), help="metres added last")
    p.add_argument("--scenario", default=None, help="Waymo: scenario id or record index (default: the first)")


def _read(args: argparse.Namespace):
    from smarts.replay.load import read_recording

    return read_recording(
        args.format, args.path, coordinates=args.coordinates, swap_xy=args.swap_xy, flip_y=args.flip_y,
        offset=tuple(args.offset), scenario=args.scenario,
    )  # fmt: skip


def summary(rec) -> dict:
    """What ``info`` prints: counts, times and extent of a recording."""
    types = {VehicleType(int(t)).name.lower(): int(n) for t, n in zip(*np.unique(rec.vtype, return_counts=True))}
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
    if rec.road_map is not None:
        out["map_lanes"] = len(rec.road_map.lane_ids)
    return out


def _info(args: argparse.Namespace) -> int:
    try:
        info = summary(_read(args))
    except ReplayError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(info))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"{info['format']} recording {info['path']}", show_header=False)
    e = info["extent"]
    rows = [
        ("vehicles", str(info["vehicles"])),
        ("most at once", str(info["max_at_once"])),
        ("duration", f"{info['duration_s']:.1f} s"),
        ("frames", f"{info['frames']} ({info['frame_s']:g} s each)"),
        ("samples", str(info["samples"])),
        ("extent", f"x {e['xmin']:.1f} .. {e['xmax']:.1f} m, y {e['ymin']:.1f} .. {e['ymax']:.1f} m"),
        ("types", ", ".join(f"{k} {v}" for k, v in info["types"].items())),
    ]
    if "map_lanes" in info:
        rows.append(("map lanes", str(info["map_lanes"])))
    for key, value in rows:
        table.add_row(key, value)
    Console(width=None if sys.stdout.isatty() else 200, highlight=False).print(table)
    return 0


def _show(args: argparse.Namespace) -> int:
    from smarts.replay.render import render

    try:
        rec = _read(args)
        road_map = None
        if args.map is not None:
            from smarts.maps import load_map

            road_map = load_map(args.map)
        n = render(rec, args.out, road_map=road_map, time=args.time, fps=args.fps, width=args.width,
                   start=args.start, duration=args.duration)  # fmt: skip
    except (ReplayError, MapError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"wrote {args.out} ({n} frame{'s' if n != 1 else ''})")
    return 0
