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
from dataclasses import dataclass
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


@dataclass(frozen=True)
class _Reading:
    """How every recording of the folder is read (the suite's replay sections repeat it)."""

    fmt: str
    coordinates: str
    swap_xy: bool
    flip_y: bool
    offset: tuple[float, float]
    reactive: str

    def section(self, path: str, scenario: str | None) -> dict:
        """A scenario's ``replay`` section (defaults left out), before the take-over is chosen."""
        replay: dict = {"format": self.fmt, "path": path}
        if scenario is not None:
            replay["scenario"] = scenario
        if self.fmt == "ngsim":
            replay["coordinates"] = self.coordinates
        if self.swap_xy:
            replay["swap_xy"] = True
        if self.flip_y:
            replay["flip_y"] = True
        if tuple(self.offset) != (0.0, 0.0):
            replay["offset"] = [float(self.offset[0]), float(self.offset[1])]
        if self.reactive != "off":
            replay["reactive"] = self.reactive
        return replay

    def spec(self, source: Path, scenario: str | None) -> ReplaySpec:
        return ReplaySpec(format=self.fmt, path=str(Path(source).resolve()), coordinates=self.coordinates,
                          swap_xy=self.swap_xy, flip_y=self.flip_y,
                          offset=(float(self.offset[0]), float(self.offset[1])), scenario=scenario)  # fmt: skip


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

    out = Path(out)
    if fmt == "ngsim" and map_path is None:
        raise ReplayError("--map: NGSIM recordings have no map of their own; name the map they run on")
    base = out.parent.resolve()
    reading = _Reading(fmt, coordinates, swap_xy, flip_y, tuple(offset), reactive)
    fixed_map = load_map(Path(map_path)) if map_path is not None else None
    map_value = REPLAY_MAP if fixed_map is None else os.path.relpath(Path(map_path).resolve(), base)
    entries, skipped, names = [], [], set()
    for source, scenario in scenario_sources(Path(folder), fmt):
        label = f"{source.name}" + (f" (scenario {scenario})" if scenario is not None else "")
        try:
            rec, road_map = _recording_and_map(reading.spec(source, scenario), label, fixed_map)
        except (ReplayError, ScenarioError, MapError) as err:
            skipped.append(str(err))
            continue
        if road_map is None:
            skipped.append(f"{label}: the recording has no map of its own; give --map")
            continue
        chosen, reasons = _take_over(rec, road_map, vehicles, label)
        if chosen is None:
            skipped.append(f"{label}: " + ("; ".join(reasons[:3]) if reasons else "no vehicle to take over"))
            continue
        replay = reading.section(os.path.relpath(Path(source).resolve(), base), scenario)
        entries.append(_entry(rec, chosen, replay, map_value, source, scenario, names))
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


def _recording_and_map(spec: ReplaySpec, label: str, fixed_map):
    """The recording and the map it runs on (the given one, else its own lanes; None: neither)."""
    from smarts.replay.lane_map import compile_lane_map
    from smarts.replay.load import plan_replay

    rec = plan_replay(spec, None, label).recording
    if fixed_map is not None:
        return rec, fixed_map
    return rec, compile_lane_map(rec.road_map) if rec.road_map is not None else None


def _take_over(rec: Recording, road_map, vehicles: list[str] | None, label: str):
    """The first candidate recorded long enough whose drive is a mission on the map, as
    ``(id, start, end)`` (None if none), and why the others were passed over."""
    from smarts.replay.load import TakeOver, take_over_mission

    reasons = []
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
        return (vid, start, end), reasons
    return None, reasons


def _entry(rec: Recording, chosen, replay: dict, map_value: str, source: Path, scenario, names: set) -> dict:
    """The suite entry of one take-over: a unique name, difficulty by the most road users at
    once, a time limit from the recorded drive."""
    from smarts.replay.load import most_at_once

    vid, start, end = chosen
    replay["take_over"] = {"ego": vid}
    replay["start"] = round(start, 6)
    peak = most_at_once(rec, start)
    body = {"map": map_value, "replay": replay, "agents": [{"id": "ego"}]}
    if peak + 1 > DEFAULT_CAPACITY:
        body["vehicle_capacity"] = int(peak + 8)
    entry_name = _name(
        f"{Path(source).stem}_{scenario}_{vid}" if scenario is not None else f"{Path(source).stem}_{vid}"
    )
    while entry_name in names:
        entry_name += "_"
    names.add(entry_name)
    difficulty = next((level for limit, level in DIFFICULTY if peak < limit), "hard")
    return {
        "name": entry_name,
        "difficulty": difficulty,
        "time_limit": math.ceil(((end - start) * TIME_FACTOR + TIME_SLACK) * 10) / 10,
        "scenario": body,
    }
