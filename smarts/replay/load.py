"""Reading a scenario's ``replay:`` section: the recording, its window, take-overs and map.

``load_recording`` dispatches on the format and keeps the last few recordings in memory (keyed by
the file's path, size and modification time and the reading options), so building an env's map and
its providers reads a large file once. ``ReplayPlan`` checks the section against the recording
(unknown take-over or filter ids, take-over vehicles absent at the start) with errors that name
the scenario file and field.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError, ScenarioError
from smarts.core.spec.replay import ReplaySpec
from smarts.replay.recording import DRIVABLE_KINDS, FRAME_EPS, TIME_TOLERANCE, Recording

_CACHE: OrderedDict[tuple, Recording] = OrderedDict()
_CACHE_SIZE = 4


def replay_path(replay: ReplaySpec, base_dir: Path | None) -> Path:
    path = Path(replay.path).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    return path


def read_recording(
    fmt: str,
    path: str | Path,
    *,
    coordinates: str = "local",
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
    scenario: str | None = None,
) -> Recording:
    """Read a recording of ``fmt`` (ngsim, argoverse2, waymo) from ``path`` (cached). ``scenario``
    picks a Waymo scenario (id or record index) or an NGSIM site (the ``Location`` of the data
    portal's file)."""
    path = Path(path)
    if not path.exists():
        raise ReplayError(f"{path}: {fmt} recording does not exist")
    if fmt == "argoverse2" and scenario is not None:
        raise ReplayError(f"{path}: scenario {scenario!r}: an Argoverse 2 scenario is a folder of its own (name it "
                          "in path)")  # fmt: skip
    stat = path.stat()
    key = (
        fmt,
        str(path.resolve()),
        stat.st_size,
        stat.st_mtime_ns,
        coordinates,
        swap_xy,
        flip_y,
        tuple(offset),
        scenario,
    )
    rec = _CACHE.get(key)
    if rec is not None:
        _CACHE.move_to_end(key)
        return rec
    options = dict(swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    if fmt == "ngsim":
        from smarts.replay.ngsim import read_ngsim

        rec = read_ngsim(path, coordinates=coordinates, location=scenario, **options)
    elif fmt == "argoverse2":
        from smarts.replay.argoverse2 import read_argoverse2

        rec = read_argoverse2(path, **options)
    elif fmt == "waymo":
        from smarts.replay.waymo import read_waymo

        rec = read_waymo(path, scenario=scenario, **options)
    else:
        raise ReplayError(f"{path}: unknown replay format {fmt!r}; expected ngsim, argoverse2 or waymo")
    _CACHE[key] = rec
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return rec


def load_recording(replay: ReplaySpec, base_dir: Path | None, source: str = "<dict>") -> Recording:
    """The recording a scenario's replay section names; read errors name the scenario too."""
    try:
        return read_recording(
            replay.format,
            replay_path(replay, base_dir),
            coordinates=replay.coordinates,
            swap_xy=replay.swap_xy,
            flip_y=replay.flip_y,
            offset=replay.offset,
            scenario=replay.scenario,
        )
    except ReplayError as err:
        raise ReplayError(f"{source}: replay.path: {err}") from None


@dataclass
class TakeOver:
    """Where an agent taking over a recorded vehicle starts and where its mission ends."""

    agent_id: str
    vehicle_id: str
    table_id: str
    start_xy: np.ndarray
    start_heading: float
    start_speed: float
    goal_xy: np.ndarray


@dataclass
class ReplayPlan:
    """A replay section checked against its recording: the vehicles, the window and take-overs."""

    recording: Recording
    start: float
    duration: float | None
    take_overs: list[TakeOver]


def plan_replay(replay: ReplaySpec, base_dir: Path | None, source: str = "<dict>") -> ReplayPlan:
    """Read the recording and check the section's ids and window against it."""
    from smarts.replay.provider import table_id

    rec = load_recording(replay, base_dir, source)
    where = f"{source}: replay"
    problems: list[str] = []
    known = rec.index_of
    if replay.vehicles is not None:
        unknown = [v for v in replay.vehicles if v not in known]
        if unknown:
            problems.append(f"{where}.vehicles: no vehicle(s) {', '.join(map(repr, unknown))} in {rec.source} "
                            f"({_some(rec.ids)})")  # fmt: skip
        keep = np.zeros(rec.num_vehicles, dtype=bool)
        keep[[known[v] for v in replay.vehicles if v in known]] = True
        for v in replay.take_over.values():  # a taken-over vehicle is always replayed until taken
            if v in known:
                keep[known[v]] = True
        rec = rec.select(keep)
        known = rec.index_of
    for agent, vid in replay.take_over.items():
        if vid not in known:
            what = rec.skipped.get(vid)
            if what is not None:
                problems.append(f"{where}.take_over.{agent}: {vid!r} in {rec.source} is {what}, which is not replayed; "
                                f"an agent takes over a vehicle ({_some(_drivable(rec))})")  # fmt: skip
            else:
                problems.append(f"{where}.take_over.{agent}: no vehicle {vid!r} in {rec.source} ({_some(rec.ids)})")
        elif rec.kind[known[vid]] not in DRIVABLE_KINDS:
            problems.append(f"{where}.take_over.{agent}: {vid!r} in {rec.source} is a {rec.kind_name(known[vid])}, not a "
                            f"vehicle; an agent takes over a vehicle ({_some(_drivable(rec))})")  # fmt: skip
    if problems:
        raise ScenarioError("\n".join(problems))
    taken = [known[v] for v in replay.take_over.values()]
    start = replay.start
    if start is None:
        start = max((rec.entry_time(k) for k in taken), default=0.0)
    if start > rec.duration + TIME_TOLERANCE * rec.dt:
        raise ScenarioError(f"{where}.start: the recording lasts {rec.duration:g} s, got {start:g}")
    take_overs = []
    for (agent, vid), k in zip(replay.take_over.items(), taken):
        entry, exit_ = rec.entry_time(k), rec.exit_time(k)
        if not entry - TIME_TOLERANCE * rec.dt <= start <= exit_ + TIME_TOLERANCE * rec.dt:
            problems.append(
                f"{where}.take_over.{agent}: vehicle {vid!r} is recorded from {entry:g} s to {exit_:g} s, not at "
                f"the start ({start:g} s); set replay.start within that time or leave it out"
            )
            continue
        _, state = rec.state_at(rec.frame_of(start), np.array([k]))
        track = rec.track(k)
        take_overs.append(TakeOver(agent, vid, table_id(vid), state[:2, 0].copy(), float(state[2, 0]),
                                   float(state[3, 0]), track[-1, :2].copy()))  # fmt: skip
    if problems:
        raise ScenarioError("\n".join(problems))
    return ReplayPlan(rec, float(start), replay.duration, take_overs)


def most_at_once(rec: Recording, start: float = 0.0, duration: float | None = None) -> int:
    """The most vehicles recorded at one frame between ``start`` and ``start + duration`` s."""
    if rec.num_vehicles == 0:
        return 0
    lo = int(np.floor(rec.frame_of(start) + FRAME_EPS))
    hi = int(rec.last.max())
    if duration is not None:
        hi = min(hi, int(np.floor(rec.frame_of(start + duration) + FRAME_EPS)))
    if hi < lo:
        return 0
    first = np.maximum(rec.first, lo)
    last = np.minimum(rec.last, hi)
    inside = first <= last
    if not inside.any():
        return 0
    # entries (+1) and exits (-1, the frame after the last) in frame order, exits first on a tie:
    # memory for the road users, not for the frames between them
    frames = np.concatenate([first[inside], last[inside] + 1])
    change = np.concatenate([np.ones(int(inside.sum()), np.int64), -np.ones(int(inside.sum()), np.int64)])
    order = np.lexsort((change, frames))
    return int(np.cumsum(change[order]).max())


def check_capacity(plan: ReplayPlan, capacity: int, agents: int, source: str = "<dict>") -> None:
    """A scenario's vehicle table must hold its agents and the most recorded vehicles at once."""
    peak = most_at_once(plan.recording, plan.start, plan.duration)
    need = peak + agents - len(plan.take_overs)  # a taken-over vehicle is its agent's row
    if need > capacity:
        raise ScenarioError(
            f"{source}: vehicle_capacity: the replay has up to {peak} vehicles at once and the scenario "
            f"{agents} agent(s): expected at least {need}, got {capacity}"
        )


def _drivable(rec: Recording) -> list[str]:
    return [vid for vid, kind in zip(rec.ids, rec.kind.tolist()) if kind in DRIVABLE_KINDS]


def _some(ids: list[str], n: int = 8) -> str:
    head = ", ".join(ids[:n])
    return f"vehicles: {head}{', ...' if len(ids) > n else ''} ({len(ids)} in all)"


GOAL_RADIUS = 3.0
"""m: a taken-over vehicle's mission is reached within this distance of its last recorded position."""


def take_over_mission(road_map, take: TakeOver, where: str):
    """The mission of an agent taking over a recorded vehicle: it starts on the lane nearest the
    vehicle's pose at the start, and its goal is the vehicle's last recorded position."""
    from smarts.core.errors import MapError
    from smarts.core.spec.scenario import GoalSpec, MissionSpec, StartSpec
    from smarts.maps import project
    from smarts.maps.errors import NoRouteError
    from smarts.maps.routing import shortest_route

    proj = project(road_map, take.start_xy[None, :], np.array([take.start_heading]))
    lane = int(proj.lane[0])
    sx, sy = (float(v) for v in take.start_xy)
    gx, gy = (float(v) for v in take.goal_xy)
    if lane < 0:
        raise MapError(
            f"{where}: vehicle {take.vehicle_id!r} starts at ({sx:.1f}, {sy:.1f}), which is on no lane of "
            f"{road_map.source}; line the recording up with the map (replay.coordinates, swap_xy, flip_y, offset)"
        )
    goal_lane = int(project(road_map, take.goal_xy[None, :]).lane[0])
    if goal_lane < 0:
        raise MapError(
            f"{where}: vehicle {take.vehicle_id!r} ends at ({gx:.1f}, {gy:.1f}), which is off the map "
            f"{road_map.source} (on no lane; the recording runs beyond the map): take over a vehicle whose track "
            "ends on the map"
        )
    try:
        shortest_route(road_map, lane, goal_lane)
    except NoRouteError:
        raise MapError(
            f"{where}: vehicle {take.vehicle_id!r}: no route on {road_map.source} from where it starts "
            f"({sx:.1f}, {sy:.1f}, lane {road_map.lane_ids[lane]!r}) to where it ends ({gx:.1f}, {gy:.1f}, lane "
            f"{road_map.lane_ids[goal_lane]!r})"
        ) from None
    road = road_map.road_ids[int(road_map.lane_road[lane])]
    offset = float(np.clip(proj.s[0], 0.0, road_map.lane_length[lane]))
    start = StartSpec(road=road, lane=int(road_map.lane_index[lane]), offset=offset,
                      speed=max(take.start_speed, 0.0), heading=take.start_heading)  # fmt: skip
    goal = GoalSpec(position=(float(take.goal_xy[0]), float(take.goal_xy[1])), radius=GOAL_RADIUS)
    return MissionSpec(start=start, goal=goal)


def replay_road_map(replay: ReplaySpec, base_dir: Path | None, source: str = "<dict>"):
    """The RoadMap compiled from the recording's own map (Argoverse 2, Waymo)."""
    from smarts.replay.lane_map import compile_lane_map

    rec = load_recording(replay, base_dir, source)
    if rec.road_map is None:
        raise ScenarioError(f"{source}: map: the {replay.format} recording {rec.source} has no map of its own")
    return compile_lane_map(rec.road_map)
