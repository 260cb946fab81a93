"""The episode log: the one stable input of the benchmark metrics.

Metrics are computed from these logs and never from a live simulator, so training, evaluation,
the benchmark runner and anyone with their own simulator score with the same code.

Layout
------
One episode = one :class:`EpisodeLog`: metadata plus, per mission vehicle (agent), an
:class:`AgentTrace` of equal-length 1-D arrays over the agent's steps. Row ``k`` (counting from
0) is the state *after* the agent's ``k+1``-th step, so the first row's ``time`` is one step
after the start (> 0): the reset state is not a row. An agent's rows end when its mission ends
(goal, collision, time out, ...) and never go past the scenario's time limit: a row with
``time > time_limit + 1e-6`` is an error, so no metric can count an arrival after the limit.
The initial route distance, measured at the mission start (the reset state) before any step, is
metadata. Values that need a previous state (jerks) use the reset state for the first row.

Per-step columns (SI units):

=========================  =====  =====================================================
column                     type   meaning
=========================  =====  =====================================================
time                       float  seconds since the episode start; strictly increasing
x, y                       float  position of the bounding-box centre (m)
heading                    float  rad, 0 = +x, counter-clockwise positive
speed                      float  m/s
accel_long, accel_lat      float  m/s^2 in the vehicle frame (lateral + left)
jerk_long, jerk_lat        float  m/s^3 in the vehicle frame
lane_offset                float  m, lateral offset from the lane centre (+ left);
                                  may be NaN on rows where ``off_road`` is set
lane_width                 float  m, width of the current lane; NaN allowed where off_road
speed_limit                float  m/s of the current lane, > 0
wrong_way                  bool   driving against the road direction
partial_off_road           bool   at least one wheel off the drivable area
off_road                   bool   the vehicle is fully off the drivable area
route_distance_to_goal     float  m, distance along the planned route to the goal plus the
                                  lateral distance to the route when off it; >= 0
goal_reached               bool   within the goal radius on this row
follow_time_gap            float  s, time gap to the follow margin (see ``following``);
                                  only read where the lead is in lane and visible and the
                                  ego is outside the margin (NaN elsewhere); +inf allowed
in_follow_margin           bool   the ego is inside the follow margin of its lead
lead_in_lane_and_visible   bool   the lead is in the ego's lane and in sight
=========================  =====  =====================================================

"In the ego's lane" is lane continuity, not equal lane ids: the lead is in lane when it is ahead
on the ego's own lane or on a lane reached from it through successor lanes (any branch, across
road-segment boundaries and junctions), within sight (50 m between centres, along the lanes);
the gap behind ``follow_time_gap`` is then bumper to bumper along those lanes. A lead in a
neighbouring lane is not in lane. The simulator side is ``smarts.core.following.lead_state``,
the same definition the lead observation and the platoon reward read.

The three following columns are required for the ``adaptive`` task (unless the episode failed)
and optional otherwise.

Optional rule columns (absent: all false; logs of version 1 have neither):

=========================  =====  =====================================================
red_light                  bool   on this row the vehicle entered a junction lane whose
                                  signal was red at that moment
left_map                   bool   the vehicle left the map at the end of its route after
                                  this row (the map's edge, not a road edge): set only on
                                  a trace's last row; off-road flags on it are no
                                  violation (see ``smarts.benchmark.metrics.scores``)
=========================  =====  =====================================================
Any further 1-D per-step arrays may ride along in ``AgentTrace.extra`` (checked for length only).

Episode metadata: scenario name, task (``collaborative`` | ``adaptive``), episode index, seed,
dt (s), time limit (s), goal radius (m), agent ids, initial route distance per agent (m), an
optional failure reason (the episode did not finish normally, e.g. the agent raised), an
optional ``end_time`` (when the scenario ended: the time limit, or earlier when a following
task's lead left the map; a vehicle whose rows stop before it did not complete the scenario),
``signals`` (how many signal-controlled junction connections the map has: the red-light rule
enters RC only where there are signals; 0 when absent) and a free-form JSON ``info`` mapping.

The scene (optional, :class:`SceneTrace`): the other road users near the agents (leads, social
agents, traffic, replayed vehicles, pedestrians) and the signal colours at every row time, so a
viewer or a plot can show the whole episode. The metrics never read it. Sizes are kept modest:
only road users within :data:`SCENE_RADIUS` of an agent or a lead, positions and speeds as
float32, sizes and roles once per road user.

On disk: one ``.npz`` per episode (:func:`write_episode` / :func:`read_episode`), never pickled.
The metadata is a JSON string stored as the ``metadata`` array; agent ``i`` (in ``agent_ids``
order) stores column ``c`` as the array ``agents/<i>/<c>`` and extras as ``extra/<i>/<name>``;
the scene's arrays are ``scene/<name>`` and its road-user ids, leads and radius the metadata's
``scene`` entry. Version 2 added the scene, ``signals`` and the rule columns; version 1 logs are
read as before.
"""

from __future__ import annotations

import csv
import json
import math
import os
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smarts.core.errors import LogError
from smarts.files import atomic_write
from smarts.npz import read_npz, write_npz

FORMAT_NAME = "smarts-episode-log"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
"""Versions this reader accepts (1: no scene, no signal count, no rule columns)."""
TASKS = ("collaborative", "adaptive")
SCENE_RADIUS = 80.0
"""m: road users farther than this from every agent and lead are left out of a log's scene."""

FLOAT_COLUMNS = (
    "time",
    "x",
    "y",
    "heading",
    "speed",
    "accel_long",
    "accel_lat",
    "jerk_long",
    "jerk_lat",
    "lane_offset",
    "lane_width",
    "speed_limit",
    "route_distance_to_goal",
)
BOOL_COLUMNS = ("wrong_way", "partial_off_road", "off_road", "goal_reached")
FOLLOW_COLUMNS = ("follow_time_gap", "in_follow_margin", "lead_in_lane_and_visible")
RULE_COLUMNS = ("red_light", "left_map")
"""Optional bool columns of version 2 (absent: all false)."""
REQUIRED_COLUMNS = FLOAT_COLUMNS + BOOL_COLUMNS
ALL_COLUMNS = REQUIRED_COLUMNS + FOLLOW_COLUMNS + RULE_COLUMNS
_BOOL_KINDS = set(BOOL_COLUMNS) | {"in_follow_margin", "lead_in_lane_and_visible"} | set(RULE_COLUMNS)
# Columns that are undefined once the vehicle has left the road entirely.
_ON_ROAD_ONLY = ("lane_offset", "lane_width")


@dataclass(eq=False)
class AgentTrace:
    """One mission vehicle's per-step arrays; see the module docstring for units and meaning."""

    time: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    accel_long: np.ndarray
    accel_lat: np.ndarray
    jerk_long: np.ndarray
    jerk_lat: np.ndarray
    lane_offset: np.ndarray
    lane_width: np.ndarray
    speed_limit: np.ndarray
    wrong_way: np.ndarray
    partial_off_road: np.ndarray
    off_road: np.ndarray
    route_distance_to_goal: np.ndarray
    goal_reached: np.ndarray
    follow_time_gap: np.ndarray | None = None
    in_follow_margin: np.ndarray | None = None
    lead_in_lane_and_visible: np.ndarray | None = None
    red_light: np.ndarray | None = None
    """Entered a junction lane on red on this row (optional; absent: never)."""
    left_map: np.ndarray | None = None
    """Left the map at its route's end after this row (optional; only the last row may be set)."""
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Lists and tuples become arrays; dtypes are checked by validation, not coerced here.
        for name in ALL_COLUMNS:
            value = getattr(self, name)
            if value is not None and not isinstance(value, np.ndarray):
                setattr(self, name, np.asarray(value))
        self.extra = {k: np.asarray(v) for k, v in self.extra.items()}

    @property
    def num_steps(self) -> int:
        return int(np.shape(self.time)[0]) if np.ndim(self.time) >= 1 else 0

    def columns(self) -> dict[str, np.ndarray]:
        """The present standard columns, in the documented order."""
        return {n: getattr(self, n) for n in ALL_COLUMNS if getattr(self, n) is not None}

    @classmethod
    def empty(cls, with_following: bool = False) -> AgentTrace:
        """A zero-step trace (for a failed episode whose agent never stepped)."""
        cols: dict[str, Any] = {
            n: np.zeros(0, dtype=bool if n in _BOOL_KINDS else np.float64)
            for n in (REQUIRED_COLUMNS + FOLLOW_COLUMNS if with_following else REQUIRED_COLUMNS)
        }
        return cls(**cols)

    def flag(self, name: str) -> np.ndarray:
        """An optional bool column, all false where the log does not have it."""
        value = getattr(self, name)
        return np.zeros(self.num_steps, dtype=bool) if value is None else value

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, AgentTrace):
            return NotImplemented
        mine, theirs = self.columns(), other.columns()
        if mine.keys() != theirs.keys() or self.extra.keys() != other.extra.keys():
            return False
        pairs = [(mine[k], theirs[k]) for k in mine]
        pairs += [(self.extra[k], other.extra[k]) for k in self.extra]
        return all(np.array_equal(a, b, equal_nan=a.dtype.kind == "f") for a, b in pairs)


@dataclass(eq=False)
class SceneTrace:
    """The other road users near the agents and the signal colours, per row time (see the module
    docstring). Road users are rows ``offsets[k]:offsets[k + 1]`` of the flat arrays at time
    ``time[k]``; ``index`` points into ``ids`` (and ``length``, ``width``, ``role``, one per road
    user); ``signals[k]`` are the colours of the map's signal-controlled connections
    (``smarts.traffic.signals``: 0 none, 1 red, 2 yellow, 3 green) in the map's connection order.
    ``leads``: agent id -> the id of the vehicle it follows."""

    time: np.ndarray
    offsets: np.ndarray
    index: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    ids: list[str]
    length: np.ndarray
    width: np.ndarray
    role: np.ndarray
    signals: np.ndarray
    leads: dict[str, str] = field(default_factory=dict)
    radius: float = SCENE_RADIUS

    ARRAYS = {
        "time": (np.float64, 1), "offsets": (np.int64, 1), "index": (np.int32, 1), "x": (np.float32, 1),
        "y": (np.float32, 1), "heading": (np.float32, 1), "speed": (np.float32, 1), "length": (np.float32, 1),
        "width": (np.float32, 1), "role": (np.int8, 1), "signals": (np.int8, 2),
    }  # fmt: skip

    @property
    def num_rows(self) -> int:
        return int(len(self.time))

    def at(self, k: int) -> slice:
        """The flat-array slice of row ``k``."""
        return slice(int(self.offsets[k]), int(self.offsets[k + 1]))

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(getattr(self, name), dtype=dtype) for name, (dtype, _) in self.ARRAYS.items()}

    def metadata(self) -> dict[str, Any]:
        return {"ids": list(self.ids), "leads": dict(self.leads), "radius": float(self.radius)}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SceneTrace):
            return NotImplemented
        return self.metadata() == other.metadata() and all(
            np.array_equal(a, b) for a, b in zip(self.arrays().values(), other.arrays().values())
        )


@dataclass(eq=False)
class EpisodeLog:
    """One episode: metadata and the trace of every mission vehicle, keyed by agent id."""

    scenario: str
    task: str
    episode: int
    seed: int | None
    dt: float
    time_limit: float
    goal_radius: float
    agents: dict[str, AgentTrace]
    initial_route_distance: dict[str, float]
    failure: str | None = None
    """Why the episode did not finish normally (e.g. the agent raised); None when it did."""
    end_time: float | None = None
    """Seconds since the start when the scenario ended: its time limit, or earlier when a
    following task's lead left the map. A mission vehicle whose rows stop before it (a crash, off
    the road) did not complete the scenario; SFD counts its missing steps as lost contact. None:
    the last logged row of the episode."""
    info: dict[str, Any] = field(default_factory=dict)
    """Free-form JSON-serialisable extras (agent locator, action space, ...)."""
    signals: int = 0
    """Signal-controlled junction connections on the map (the red-light rule applies where > 0)."""
    scene: SceneTrace | None = None
    """The other road users and the signal colours (version 2; never read by the metrics)."""
    source: str | None = None
    """Where the log was read from; prefixes error messages. Not stored."""

    @property
    def agent_ids(self) -> list[str]:
        return list(self.agents)

    @property
    def failed(self) -> bool:
        return self.failure is not None

    def metadata(self) -> dict[str, Any]:
        """The JSON-serialisable metadata stored next to the arrays."""
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "scenario": self.scenario,
            "task": self.task,
            "episode": int(self.episode),
            "seed": None if self.seed is None else int(self.seed),
            "dt": float(self.dt),
            "time_limit": float(self.time_limit),
            "goal_radius": float(self.goal_radius),
            "agent_ids": self.agent_ids,
            "initial_route_distance": {a: float(d) for a, d in self.initial_route_distance.items()},
            "failure": self.failure,
            "end_time": None if self.end_time is None else float(self.end_time),
            "signals": int(self.signals),
            "scene": None if self.scene is None else self.scene.metadata(),
            "info": self.info,
        }

    def validate(self) -> None:
        """Raise :class:`LogError` on the first problem found; see :func:`validate_episode`."""
        validate_episode(self)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EpisodeLog):
            return NotImplemented
        return (
            self.metadata() == other.metadata()
            and self.agents.keys() == other.agents.keys()
            and all(self.agents[a] == other.agents[a] for a in self.agents)
            and (self.scene is None) == (other.scene is None)
            and (self.scene is None or self.scene == other.scene)
        )


# ---------------------------------------------------------------------------------- validation
def validate_episode(log: EpisodeLog) -> None:
    """Check metadata and every trace; raise :class:`LogError` naming file, agent and column.

    Checked: metadata types and ranges; per agent, that every required column is present,
    1-D, of the right kind (bool columns boolean, the rest numeric) and as long as ``time``;
    finiteness (``lane_offset``/``lane_width`` may be NaN only where ``off_road``;
    ``follow_time_gap`` may be NaN only where it is not read); ``time`` strictly increasing;
    ``speed_limit`` > 0, ``lane_width`` > 0 on road, ``route_distance_to_goal`` >= 0;
    ``time`` of the first row > 0 (the reset state is not a row) and of every row
    <= ``time_limit`` + 1e-6 (no row after the time limit).
    An episode that did not fail needs at least one agent and one step per agent.
    """
    src = log.source
    _validate_metadata(log)
    for agent_id, trace in log.agents.items():
        if not isinstance(trace, AgentTrace):
            raise LogError(
                f"expected an AgentTrace, got {type(trace).__name__}",
                source=src,
                agent=agent_id,
            )
        _validate_trace(trace, agent_id, log.task, log.failed, src, float(log.time_limit))
    if log.scene is not None:
        _validate_scene(log.scene, src)


def _validate_scene(scene: SceneTrace, src: str | None) -> None:
    """Shapes, kinds and index ranges of a scene, and finite positions."""

    def bad(name: str, problem: str) -> LogError:
        return LogError(problem, source=src, column=f"scene.{name}")

    if not isinstance(scene, SceneTrace):
        raise LogError(f"expected a SceneTrace, got {type(scene).__name__}", source=src, column="scene")
    for name, (dtype, ndim) in SceneTrace.ARRAYS.items():
        value = getattr(scene, name)
        if not isinstance(value, np.ndarray) or value.ndim != ndim or value.dtype != np.dtype(dtype):
            got = f"{value.ndim}-D {value.dtype}" if isinstance(value, np.ndarray) else type(value).__name__
            raise bad(name, f"expected a {ndim}-D {np.dtype(dtype).name} array, got {got}")
    t, n, v = len(scene.time), len(scene.index), len(scene.ids)
    off = scene.offsets
    if len(off) != t + 1 or (t + 1 and (off[0] != 0 or off[-1] != n)) or np.any(np.diff(off) < 0):
        raise bad("offsets", f"expected {t + 1} non-decreasing offsets from 0 to {n}")
    for name in ("x", "y", "heading", "speed"):
        if len(getattr(scene, name)) != n:
            raise bad(name, f"expected {n} values like scene.index, got {len(getattr(scene, name))}")
        if not np.isfinite(getattr(scene, name)).all():
            raise bad(name, "non-finite value (must be finite)")
    for name in ("length", "width", "role"):
        if len(getattr(scene, name)) != v:
            raise bad(name, f"expected one value per road user ({v}), got {len(getattr(scene, name))}")
    if n and (scene.index.min() < 0 or scene.index.max() >= v):
        raise bad("index", f"a road user outside the {v} ids")
    if len(scene.signals) != t:
        raise bad("signals", f"expected {t} rows like scene.time, got {len(scene.signals)}")
    if t > 1 and not (np.diff(scene.time) > 0).all():
        raise bad("time", "must be strictly increasing")
    if not all(isinstance(i, str) for i in scene.ids) or not isinstance(scene.leads, dict):
        raise LogError("scene ids must be strings and leads a mapping", source=src, column="metadata.scene")


def _validate_metadata(log: EpisodeLog) -> None:
    src = log.source

    def bad(fld: str, problem: str) -> LogError:
        return LogError(problem, source=src, column=f"metadata.{fld}")

    if not isinstance(log.scenario, str) or not log.scenario:
        raise bad("scenario", f"expected a non-empty string, got {log.scenario!r}")
    if log.task not in TASKS:
        raise bad("task", f"expected one of {', '.join(TASKS)}, got {log.task!r}")
    if not _is_int(log.episode) or log.episode < 0:
        raise bad("episode", f"expected an integer >= 0, got {log.episode!r}")
    if log.seed is not None and not _is_int(log.seed):
        raise bad("seed", f"expected an integer or null, got {log.seed!r}")
    for name, low_ok in (("dt", False), ("time_limit", False), ("goal_radius", True)):
        value = getattr(log, name)
        if not _is_number(value) or not math.isfinite(value) or value < 0 or (value == 0 and not low_ok):
            need = ">= 0" if low_ok else "> 0"
            raise bad(name, f"expected a finite number {need}, got {value!r}")
    if log.failure is not None and not isinstance(log.failure, str):
        raise bad("failure", f"expected a string or null, got {log.failure!r}")
    if not _is_int(log.signals) or log.signals < 0:
        raise bad("signals", f"expected an integer >= 0, got {log.signals!r}")
    if not isinstance(log.info, dict):
        raise bad("info", f"expected a mapping, got {type(log.info).__name__}")
    if not isinstance(log.agents, dict):
        raise bad(
            "agent_ids",
            f"expected a dict of agent id -> AgentTrace, got {type(log.agents).__name__}",
        )
    for agent_id in log.agents:
        if not isinstance(agent_id, str) or not agent_id:
            raise bad("agent_ids", f"expected non-empty string agent ids, got {agent_id!r}")
    if not log.agents and not log.failed:
        raise bad("agent_ids", "an episode that did not fail needs at least one agent")
    dist = log.initial_route_distance
    if not isinstance(dist, dict) or set(dist) != set(log.agents):
        got = sorted(dist) if isinstance(dist, dict) else dist
        raise bad(
            "initial_route_distance",
            f"expected one entry per agent {sorted(log.agents)}, got {got!r}",
        )
    for agent_id, d in dist.items():
        if not _is_number(d) or not math.isfinite(d) or d < 0:
            raise LogError(
                f"expected a finite distance >= 0, got {d!r}",
                source=src,
                agent=agent_id,
                column="metadata.initial_route_distance",
            )
    end = log.end_time
    if end is not None:
        if not _is_number(end) or not math.isfinite(end) or end <= 0:
            raise bad("end_time", f"expected a finite number of seconds > 0 or null, got {end!r}")
        if end > log.time_limit + TIME_LIMIT_TOLERANCE:
            raise bad("end_time", f"{end!r} is after the time limit {log.time_limit!r}")
        last = max((float(t.time[-1]) for t in log.agents.values() if _is_trace_with_rows(t)), default=0.0)
        if end < last - TIME_LIMIT_TOLERANCE:
            raise bad("end_time", f"{end!r} is before the last logged row at {last!r}")


def _is_trace_with_rows(trace: Any) -> bool:
    return isinstance(trace, AgentTrace) and np.ndim(trace.time) == 1 and trace.num_steps > 0


TIME_LIMIT_TOLERANCE = 1e-6
"""Seconds a row's time may exceed the time limit (float noise), no more."""


def _validate_trace(
    trace: AgentTrace,
    agent: str,
    task: str,
    failed: bool,
    src: str | None,
    time_limit: float = math.inf,
) -> None:
    def bad(column: str, problem: str) -> LogError:
        return LogError(problem, source=src, agent=agent, column=column)

    # A failed episode is scored as worst without reading its traces, so it needs no following columns.
    required = REQUIRED_COLUMNS + (FOLLOW_COLUMNS if task == "adaptive" and not failed else ())
    _check_column_kinds(trace, required, bad)
    n = trace.time.shape[0]
    for name, value in list(trace.columns().items()) + [(f"extra.{k}", v) for k, v in trace.extra.items()]:
        if value.ndim != 1 or value.shape[0] != n:
            raise bad(
                name,
                f"has {value.shape} entries but 'time' has {n} (all columns must match)",
            )
    if n == 0:
        if not failed:
            raise bad(
                "time",
                "no steps logged (only a failed episode may have an empty trace)",
            )
        return
    _check_finite(trace, bad)
    _check_times(trace, time_limit, bad)
    _check_values(trace, n, bad)


def _check_column_kinds(trace: AgentTrace, required: tuple[str, ...], bad) -> None:
    """Every required column is present, and every present column is 1-D with the expected dtype kind."""
    for name in ALL_COLUMNS:
        value = getattr(trace, name)
        if value is None:
            if name in required:
                why = " (required for the adaptive task)" if name in FOLLOW_COLUMNS else ""
                raise bad(name, f"missing column{why}")
            continue
        if value.ndim != 1:
            raise bad(name, f"expected a 1-D array over steps, got shape {value.shape}")
        if name in _BOOL_KINDS:
            if value.dtype.kind != "b":
                raise bad(name, f"expected booleans, got dtype {value.dtype}")
        elif value.dtype.kind not in "fiu":
            raise bad(name, f"expected numbers, got dtype {value.dtype}")


def _check_finite(trace: AgentTrace, bad) -> None:
    """Float columns are finite (lane-relative ones only on rows where the vehicle is on the road)."""
    off_road = trace.off_road
    for name in FLOAT_COLUMNS:
        value = getattr(trace, name)
        finite = np.isfinite(value)
        if name in _ON_ROAD_ONLY:
            finite |= off_road
        if not finite.all():
            step = int(np.argmin(finite))
            where = " on a row where off_road is false" if name in _ON_ROAD_ONLY else ""
            raise bad(
                name,
                f"non-finite value {value[step].item()!r} at step {step}{where} (must be finite)",
            )


def _check_times(trace: AgentTrace, time_limit: float, bad) -> None:
    """Row times increase strictly, start after the reset, and end by the time limit."""
    if trace.time.shape[0] > 1 and not (np.diff(trace.time) > 0).all():
        step = int(np.argmin(np.diff(trace.time) > 0)) + 1
        raise bad(
            "time",
            f"must be strictly increasing; step {step} is {trace.time[step].item()!r} after {trace.time[step - 1].item()!r}",
        )
    if not trace.time[0] > 0:
        raise bad(
            "time",
            f"first row at {trace.time[0].item()!r} s; row k is the state after step k+1, so "
            "the first row is one step after the start (> 0; the reset state is not a row)",
        )
    late = trace.time > time_limit + TIME_LIMIT_TOLERANCE
    if late.any():
        step = int(np.argmax(late))
        raise bad(
            "time",
            f"row {step} at {trace.time[step].item()!r} s is after the time limit "
            f"{time_limit!r} s (rows end at the time limit)",
        )


def _check_values(trace: AgentTrace, n: int, bad) -> None:
    """Limits, distances, widths and gaps lie in the ranges the metrics assume; left_map only on the last row."""
    off_road = trace.off_road
    _check_range(trace.speed_limit > 0, trace.speed_limit, bad, "speed_limit", "> 0")
    _check_range(
        trace.route_distance_to_goal >= 0,
        trace.route_distance_to_goal,
        bad,
        "route_distance_to_goal",
        ">= 0",
    )
    _check_range(
        (trace.lane_width > 0) | off_road,
        trace.lane_width,
        bad,
        "lane_width",
        "> 0 on road",
    )
    if trace.left_map is not None and trace.left_map[:-1].any():
        step = int(np.argmax(trace.left_map))
        raise bad(
            "left_map", f"set on row {step} of {n}; a vehicle that left the map has no rows after (only the last row)"
        )
    if (
        trace.follow_time_gap is not None
        and trace.lead_in_lane_and_visible is not None
        and trace.in_follow_margin is not None
    ):
        read = trace.lead_in_lane_and_visible & ~trace.in_follow_margin
        gap = trace.follow_time_gap
        ok = ~read | (~np.isnan(gap) & (gap >= 0))
        _check_range(
            ok,
            gap,
            bad,
            "follow_time_gap",
            ">= 0 (not NaN) where the lead is in lane and visible and the ego is outside the follow margin",
        )


def _check_range(ok: np.ndarray, value: np.ndarray, bad, column: str, need: str) -> None:
    if not ok.all():
        step = int(np.argmin(ok))
        raise bad(column, f"value {value[step].item()!r} at step {step}; expected {need}")


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


# ------------------------------------------------------------------------------ reading/writing
def episode_filename(log: EpisodeLog) -> str:
    """A conventional file name: ``<scenario>__ep<episode>.npz`` (unsafe characters replaced)."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in log.scenario)
    return f"{safe}__ep{log.episode:05d}.npz"


def write_episode(log: EpisodeLog, path: str | os.PathLike) -> Path:
    """Validate, then write ``log`` as one compressed .npz at ``path`` (atomically; see
    ``smarts.npz``); returns it."""
    validate_episode(log)
    path = Path(path)
    try:
        meta_json = json.dumps(log.metadata(), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise LogError(
            f"metadata is not plain JSON data ({exc})",
            source=log.source,
            column="metadata.info",
        ) from None
    arrays: dict[str, np.ndarray] = {"metadata": np.array(meta_json)}
    for index, trace in enumerate(log.agents.values()):
        for name, value in trace.columns().items():
            arrays[f"agents/{index}/{name}"] = value
        for name, value in trace.extra.items():
            arrays[f"extra/{index}/{name}"] = value
    if log.scene is not None:
        arrays.update({f"scene/{name}": value for name, value in log.scene.arrays().items()})
    path.parent.mkdir(parents=True, exist_ok=True)
    # Not fsynced: a log lost to a power cut reads back invalid, and --resume runs its episode again.
    with atomic_write(path, durable=False) as fh:
        write_npz(fh, arrays)
    return path


def read_episode(path: str | os.PathLike) -> EpisodeLog:
    """Read and validate one .npz episode log; :class:`LogError` names what is wrong and where."""
    src = str(path)
    arrays = _load_arrays(path, src)
    meta = _read_metadata(arrays, src)
    agent_ids = meta["agent_ids"]
    agents = _read_agents(arrays, agent_ids, src)
    scene = _read_scene(arrays, meta.get("scene"), src)
    known = (
        tuple(f"agents/{i}/" for i in range(len(agent_ids)))
        + tuple(f"extra/{i}/" for i in range(len(agent_ids)))
        + ("scene/",)
    )
    stray = sorted(k for k in arrays if not k.startswith(known))
    if stray:
        raise LogError(
            f"arrays {stray} belong to no agent listed in metadata.agent_ids",
            source=src,
        )

    log = EpisodeLog(
        scenario=meta["scenario"],
        task=meta["task"],
        episode=meta["episode"],
        seed=meta["seed"],
        dt=meta["dt"],
        time_limit=meta["time_limit"],
        goal_radius=meta["goal_radius"],
        agents=agents,
        initial_route_distance=meta["initial_route_distance"],
        failure=meta.get("failure"),
        end_time=meta.get("end_time"),
        info=meta.get("info") or {},
        signals=meta.get("signals", 0),
        scene=scene,
        source=src,
    )
    validate_episode(log)
    return log


def _load_arrays(path: str | os.PathLike, src: str) -> dict[str, np.ndarray]:
    """Every array of the .npz (a missing file raises FileNotFoundError as is)."""
    try:
        return read_npz(path)
    except FileNotFoundError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise LogError(f"not a readable .npz episode log ({exc})", source=src) from None


def _read_metadata(arrays: dict[str, np.ndarray], src: str) -> dict:
    """Pop and check the JSON metadata entry: format, version, required fields, distinct agent ids."""
    if "metadata" not in arrays:
        raise LogError("missing the 'metadata' entry", source=src, column="metadata")
    try:
        meta = json.loads(str(arrays.pop("metadata")))
    except json.JSONDecodeError as exc:
        raise LogError(f"metadata is not valid JSON ({exc})", source=src, column="metadata") from None
    if not isinstance(meta, dict):
        raise LogError("metadata must be a JSON object", source=src, column="metadata")
    if meta.get("format") != FORMAT_NAME:
        raise LogError(
            f"expected format {FORMAT_NAME!r}, got {meta.get('format')!r}",
            source=src,
            column="metadata.format",
        )
    if meta.get("version") not in READABLE_VERSIONS:
        raise LogError(
            f"unsupported version {meta.get('version')!r} (this reader knows {', '.join(map(str, READABLE_VERSIONS))})",
            source=src,
            column="metadata.version",
        )
    keys = (
        "scenario",
        "task",
        "episode",
        "seed",
        "dt",
        "time_limit",
        "goal_radius",
        "agent_ids",
        "initial_route_distance",
    )
    for key in keys:
        if key not in meta:
            raise LogError("missing metadata field", source=src, column=f"metadata.{key}")
    agent_ids = meta["agent_ids"]
    if not isinstance(agent_ids, list) or len(set(map(str, agent_ids))) != len(agent_ids):
        raise LogError(
            f"expected a list of distinct agent ids, got {agent_ids!r}",
            source=src,
            column="metadata.agent_ids",
        )
    return meta


def _read_agents(arrays: dict[str, np.ndarray], agent_ids: list, src: str) -> dict[str, AgentTrace]:
    """One trace per listed agent from its ``agents/<i>/`` columns and ``extra/<i>/`` arrays."""
    agents: dict[str, AgentTrace] = {}
    for index, agent_id in enumerate(agent_ids):
        prefix = f"agents/{index}/"
        cols = {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)}
        unknown = sorted(set(cols) - set(ALL_COLUMNS))
        if unknown:
            raise LogError(
                f"unknown column(s) {unknown} (extras belong under 'extra/')",
                source=src,
                agent=agent_id,
            )
        for name in REQUIRED_COLUMNS:
            if name not in cols:
                raise LogError("missing column", source=src, agent=agent_id, column=name)
        xprefix = f"extra/{index}/"
        extra = {k[len(xprefix) :]: v for k, v in arrays.items() if k.startswith(xprefix)}
        agents[agent_id] = AgentTrace(**cols, extra=extra)
    return agents


def _read_scene(arrays: dict[str, np.ndarray], meta: Any, src: str) -> SceneTrace | None:
    """The scene of a version 2 log (None when it has none); checked by :func:`validate_episode`."""
    names = {k[len("scene/") :] for k in arrays if k.startswith("scene/")}
    if meta is None and not names:
        return None
    if not isinstance(meta, dict) or not isinstance(meta.get("ids"), list):
        raise LogError("expected a mapping with the road users' ids", source=src, column="metadata.scene")
    missing = sorted(set(SceneTrace.ARRAYS) - names)
    if missing:
        raise LogError(f"missing scene array(s) {missing}", source=src, column="scene")
    unknown = sorted(names - set(SceneTrace.ARRAYS))
    if unknown:
        raise LogError(f"unknown scene array(s) {unknown}", source=src, column="scene")
    radius = meta.get("radius", SCENE_RADIUS)
    return SceneTrace(**{n: arrays[f"scene/{n}"] for n in SceneTrace.ARRAYS}, ids=meta["ids"],
                      leads=meta.get("leads") or {}, radius=float(radius) if _is_number(radius) else SCENE_RADIUS)  # fmt: skip


def read_episodes(
    paths: str | os.PathLike | Iterable[str | os.PathLike],
) -> list[EpisodeLog]:
    """Read logs from files and/or folders (every ``*.npz`` below a folder), sorted by path."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    files: list[Path] = []
    for p in map(Path, paths):
        files.extend(sorted(p.rglob("*.npz")) if p.is_dir() else [p])
    return [read_episode(f) for f in files]


# ------------------------------------------------------------------------------------- export
def _rows(log: EpisodeLog) -> Iterator[dict[str, Any]]:
    for agent_id, trace in log.agents.items():
        cols = trace.columns()
        cols.update({f"extra.{k}": v for k, v in trace.extra.items()})
        lists = {k: v.tolist() for k, v in cols.items()}
        for step in range(trace.num_steps):
            row: dict[str, Any] = {
                "scenario": log.scenario,
                "episode": log.episode,
                "agent": agent_id,
                "step": step,
            }
            row.update({k: v[step] for k, v in lists.items()})
            yield row


def export_jsonl(log: EpisodeLog, path: str | os.PathLike) -> Path:
    """One JSON object per agent step (non-finite floats become null) for tools outside numpy."""
    path = Path(path)
    with path.open("w", encoding="utf-8") as fh:
        for row in _rows(log):
            clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}
            fh.write(json.dumps(clean, allow_nan=False) + "\n")
    return path


def export_csv(log: EpisodeLog, path: str | os.PathLike) -> Path:
    """One CSV row per agent step; absent columns are left empty, non-finite floats as nan/inf."""
    path = Path(path)
    header = ["scenario", "episode", "agent", "step", *ALL_COLUMNS]
    extras = sorted({f"extra.{k}" for t in log.agents.values() for k in t.extra})
    with path.open("w", encoding="utf-8", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=header + extras, restval="")
        writer.writeheader()
        for row in _rows(log):
            writer.writerow(row)
    return path


__all__ = [
    "ALL_COLUMNS",
    "RULE_COLUMNS",
    "SCENE_RADIUS",
    "SceneTrace",
    "BOOL_COLUMNS",
    "FLOAT_COLUMNS",
    "FOLLOW_COLUMNS",
    "FORMAT_VERSION",
    "REQUIRED_COLUMNS",
    "TASKS",
    "AgentTrace",
    "EpisodeLog",
    "LogError",
    "episode_filename",
    "export_csv",
    "export_jsonl",
    "read_episode",
    "read_episodes",
    "validate_episode",
    "write_episode",
]
