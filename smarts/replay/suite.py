"""Benchmark suites from recorded scenes (``smarts replay suite``).

Each scenario of a folder (an NGSIM file, each scenario of each Waymo TFRecord, each Argoverse 2
scenario folder) becomes one suite scenario: an agent takes over the recorded ego (or a chosen
vehicle) from when it is first recorded and drives to where it ended, among the other recorded road
users (which may turn reactive). The suite is a ``collaborative`` task (missions with goals, scored
with PR, RC, Humanness and MTE), read by ``smarts.benchmark.suites.load_suite`` and run with
``python -m train benchmark --suite``. A candidate whose vehicle starts or ends off the map, or that
no route connects, is left out with the reason.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import yaml

from smarts.core.errors import MapError, ReplayError, ScenarioError
from smarts.core.spec.replay import REPLAY_MAP, ReplaySpec
from smarts.core.spec.scenario import ScenarioSpec
from smarts.replay.recording import DRIVABLE_KINDS, Recording

TIME_FACTOR = 1.5
"""A scenario's time limit is the recorded drive's time this many times over, plus :data:`TIME_SLACK`."""
TIME_SLACK = 2.0
"""s added to every time limit (a short recorded drive still leaves time to start)."""
DIFFICULTY = ((10, "easy"), (30, "medium"))
"""Most recorded road users at once below which a scenario is easy or medium (else hard)."""
MIN_DRIVE = 2.0
"""s: a vehicle recorded for less is not taken over (there is nothing to drive)."""
DEFAULT_CAPACITY = ScenarioSpec.model_fields["vehicle_capacity"].default


def scenario_sources(folder: Path, fmt: str) -> list[tuple[Path, str | None]]:
    """(file or folder, scenario id or None) of every scenario in ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ReplayError(f"{folder}: expected a folder of {fmt} recordings")
    if fmt == "argoverse2":
        found = [p for p in [folder, *sorted(p for p in folder.iterdir() if p.is_dir())]
                 if any(p.glob("scenario_*.parquet"))]  # fmt: skip
        return [(p, None) for p in found]
    if fmt == "ngsim":
        return [(p, None) for p in sorted(folder.iterdir()) if p.is_file() and p.suffix.lower() in (".csv", ".txt")]
    from smarts.replay.tfrecord import read_records
    from smarts.replay.waymo import find_scenario
    from smarts.replay.waymo_proto import scenario_class

    out = []
    for path in sorted(p for p in folder.iterdir() if p.is_file() and "tfrecord" in p.name):
        find_scenario(path)  # a file that is not one of Scenario records says so here
        cls = scenario_class()
        for index, data in enumerate(read_records(path)):
            out.append((path, cls.FromString(data).scenario_id or str(index)))
    return out


def _candidates(rec: Recording, vehicles: list[str] | None) -> list[str]:
    """The ids to take over: those asked for that this recording has, else its ego, else (NGSIM)
    its vehicles longest recorded first."""
    if vehicles:
        return [v for v in vehicles if v in rec.index_of]
    if rec.ego is not None:
        return [rec.ego]
    order = np.argsort(-rec.count, kind="stable")
    return [rec.ids[k] for k in order.tolist() if rec.kind[k] in DRIVABLE_KINDS]


def _name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "scenario"


def build_suite(
    folder: str | Path,
    fmt: str,
    out: str | Path,
    *,
    map_path: str | Path | None = None,
    vehicles: list[str] | None = None,
    reactive: str = "off",
    name: str | None = None,
    coordinates: str = "local",
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
) -> tuple[int, list[str]]:
    """Write the suite YAML ``out`` from the recordings in ``folder``; returns the number of
    scenarios written and one line per candidate left out (with the reason)."""
    from smarts.maps import load_map
    from smarts.replay.lane_map import compile_lane_map
    from smarts.replay.load import TakeOver, most_at_once, plan_replay, take_over_mission

    out = Path(out)
    if fmt == "ngsim" and map_path is None:
        raise ReplayError("--map: NGSIM recordings have no map of their own; name the map they run on")
    base = out.parent.resolve()
    fixed_map = load_map(Path(map_path)) if map_path is not None else None
    entries, skipped, names = [], [], set()
    for source, scenario in scenario_sources(Path(folder), fmt):
        label = f"{source.name}" + (f" (scenario {scenario})" if scenario is not None else "")
        path = os.path.relpath(Path(source).resolve(), base)
        replay = {"format": fmt, "path": path}
        if scenario is not None:
            replay["scenario"] = scenario
        if fmt == "ngsim":
            replay["coordinates"] = coordinates
        if swap_xy:
            replay["swap_xy"] = True
        if flip_y:
            replay["flip_y"] = True
        if tuple(offset) != (0.0, 0.0):
            replay["offset"] = [float(offset[0]), float(offset[1])]
        if reactive != "off":
            replay["reactive"] = reactive
        spec = ReplaySpec(format=fmt, path=str(Path(source).resolve()), coordinates=coordinates, swap_xy=swap_xy,
                          flip_y=flip_y, offset=(float(offset[0]), float(offset[1])), scenario=scenario)  # fmt: skip
        try:
            rec = plan_replay(spec, None, label).recording
            road_map = fixed_map if fixed_map is not None else (
                compile_lane_map(rec.road_map) if rec.road_map is not None else None)  # fmt: skip
        except (ReplayError, ScenarioError, MapError) as err:
            skipped.append(str(err))
            continue
        if road_map is None:
            skipped.append(f"{label}: the recording has no map of its own; give --map")
            continue
        chosen, reasons = None, []
        for vid in _candidates(rec, vehicles):
            k = rec.index_of[vid]
            start, end = rec.entry_time(k), rec.exit_time(k)
            if end - start < MIN_DRIVE:
                reasons.append(f"vehicle {vid!r} is recorded for {end - start:.1f} s only")
                continue
            _, state = rec.state_at(rec.frame_of(start), np.array([k]))
            take = TakeOver("ego", vid, "", state[:2, 0].copy(), float(state[2, 0]), float(state[3, 0]),
                            rec.track(k)[-1, :2].copy())  # fmt: skip
            try:
                take_over_mission(road_map, take, f"{label}: replay.take_over.ego")
            except MapError as err:
                reasons.append(str(err))
                continue
            chosen = (vid, start, end)
            break
        if chosen is None:
            skipped.append(f"{label}: " + ("; ".join(reasons[:3]) if reasons else "no vehicle to take over"))
            continue
        vid, start, end = chosen
        replay["take_over"] = {"ego": vid}
        replay["start"] = round(start, 6)
        peak = most_at_once(rec, start)
        body = {"map": REPLAY_MAP if fixed_map is None else os.path.relpath(Path(map_path).resolve(), base),
                "replay": replay, "agents": [{"id": "ego"}]}  # fmt: skip
        if peak + 1 > DEFAULT_CAPACITY:
            body["vehicle_capacity"] = int(peak + 8)
        entry_name = _name(
            f"{Path(source).stem}_{scenario}_{vid}" if scenario is not None else f"{Path(source).stem}_{vid}"
        )
        while entry_name in names:
            entry_name += "_"
        names.add(entry_name)
        difficulty = next((level for limit, level in DIFFICULTY if peak < limit), "hard")
        entries.append({
            "name": entry_name,
            "difficulty": difficulty,
            "time_limit": math.ceil(((end - start) * TIME_FACTOR + TIME_SLACK) * 10) / 10,
            "scenario": body,
        })  # fmt: skip
    if not entries:
        reasons = "\n  ".join(skipped) if skipped else "no scenario files"
        raise ReplayError(f"{folder}: no scenario to take over in the {fmt} recordings:\n  {reasons}")
    suite = {
        "name": name or out.stem,
        "task": "collaborative",
        "episodes": 1,
        "seed": 0,
        "scenarios": entries,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# Take-over scenarios from the {fmt} recordings in {folder} (smarts replay suite): the agent drives\n"
              "# the recorded vehicle to where it ended; the other road users replay as recorded.\n")  # fmt: skip
    out.write_text(header + yaml.safe_dump(suite, sort_keys=False))
    return len(entries), skipped
