"""The replay provider: recorded road users follow their tracks, interpolated to the simulation step.

Each step looks every recorded road user of the window up at once, on the recording's own clock
(``Recording.frame_of``): those whose track starts by now enter the vehicle table (pedestrians with
the pedestrian role, so observations, collisions and occlusion see them as such), those whose track
has ended leave it, and the rest get their interpolated pose and speed written into their rows.
Recorded traffic-signal states (Waymo) are written into the simulation's signals each frame. A row
handed to another provider (an agent taking a vehicle over, or the traffic model when the vehicle
turns reactive) is released for good: its recording is no longer replayed.

Reactive hand-over goes through the simulation's ``hand_over`` to a provider the env assembles
(``reactive_target``, the built-in traffic model); this package never imports traffic.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.core.geometry import wrap_scalar
from smarts.core.provider import ProviderBase
from smarts.core.vehicle_table import COLUMN, Role, VehicleType
from smarts.records import declare, freeze_fields, view
from smarts.replay.recording import FRAME_EPS, ObjectKind, Recording, interpolate

if TYPE_CHECKING:
    from smarts.core.provider import Provider
    from smarts.core.simulation import Simulation

ID_PREFIX = "replay-"
"""Vehicle table ids of recorded vehicles are this prefix and the dataset's id."""

PENDING, DRIVING, DONE = 0, 1, 2
SIGNAL_CHARS = "oryGryGry"
"""Waymo's signal state codes (unknown, arrow stop/caution/go, stop/caution/go, flashing stop and
caution) as SUMO state letters: stop red, caution yellow, go green, unknown no signal; a flashing
red is a stop and a flashing yellow a caution."""


def table_id(vehicle_id: str) -> str:
    return f"{ID_PREFIX}{vehicle_id}"


class Tracks(NamedTuple):
    """What ``_advance_tracks`` reads and keeps of the window's tracks: the provider's own arrays
    (not copies), built once with it, so each step types one record instead of eleven arrays."""

    first: np.ndarray  # float64[K] each track's first frame
    count: np.ndarray  # int64[K] its frames (cut at the window's end)
    offsets: np.ndarray  # int64[K] its first sample in x, y, heading and speed
    x: np.ndarray  # [samples] the recording's, every track's samples
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    state: np.ndarray  # int8[K] PENDING, DRIVING or DONE (kept between steps)
    row: np.ndarray  # int64[K] vehicle table row of a driven track, -1 none
    enter: np.ndarray  # int64[K] scratch: tracks entering at this step
    leave: np.ndarray  # int64[K] scratch: tracks leaving at this step


declare(Tracks)


@njit(nogil=True)
def _freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


class ReplayProvider(ProviderBase):
    """Drives the recorded vehicles of ``recording`` from ``start`` seconds (after the recording's
    first frame) for ``duration`` seconds (None: to the end)."""

    name = "replay"

    def __init__(
        self,
        recording: Recording,
        start: float = 0.0,
        duration: float | None = None,
        *,
        reactive: str = "off",
        reactive_distance: float = 10.0,
        reactive_target: Provider | None = None,
    ):
        self.recording = recording
        self.start_time = float(start)
        self.start_frame = recording.frame_of(self.start_time)
        self.end_frame = np.inf if duration is None else recording.frame_of(self.start_time + duration)
        self.reactive = reactive
        self.reactive_distance = float(reactive_distance)
        self.reactive_target = reactive_target
        # only the vehicles recorded inside the window take part
        last = recording.last
        inside = (last >= self.start_frame - FRAME_EPS) & (recording.first <= self.end_frame + FRAME_EPS)
        self.vehicles = np.flatnonzero(inside)
        self.first = recording.first[self.vehicles].astype(np.float64)
        self.count = recording.count[self.vehicles]
        self.offsets = recording.offsets[self.vehicles]
        # a track is cut at the window's end (the vehicle leaves when the window does)
        if np.isfinite(self.end_frame):
            cut = np.floor(self.end_frame + FRAME_EPS - self.first).astype(np.int64) + 1
            self.count = np.minimum(self.count, cut)
        self.table_ids = [table_id(recording.ids[v]) for v in self.vehicles.tolist()]
        n = len(self.vehicles)
        self.state = np.zeros(n, dtype=np.int8)
        self.row = np.full(n, -1, dtype=np.int64)
        self._vehicle_of_row = np.zeros(0, dtype=np.int64)
        self._dims = np.stack([recording.length[self.vehicles], recording.width[self.vehicles]])
        self._vtype = recording.vtype[self.vehicles]
        self._role = np.where(recording.kind[self.vehicles] == ObjectKind.PEDESTRIAN, int(Role.PEDESTRIAN),
                              int(Role.REPLAY))  # fmt: skip
        self._signal_tls: np.ndarray | None = None  # the map's signal index of each recorded signal
        self._signal_frame = -1
        self._enter = np.zeros(n, dtype=np.int64)  # scratch: vehicles entering / leaving this step
        self._leave = np.zeros(n, dtype=np.int64)
        self._tracks = _freeze(Tracks(
            first=self.first, count=self.count, offsets=self.offsets, x=recording.x, y=recording.y,
            heading=recording.heading, speed=recording.speed, state=self.state, row=self.row, enter=self._enter,
            leave=self._leave,
        ))  # fmt: skip
        self.handed_over: list[str] = []
        """Table ids of the vehicles handed to the traffic model this episode, in order."""

    # ------------------------------------------------------------------ episode
    def reset(self, sim: Simulation) -> None:
        self.state[:] = PENDING
        self.row[:] = -1
        self._vehicle_of_row = np.full(sim.table.capacity, -1, dtype=np.int64)
        self.handed_over = []
        self._signal_tls = None
        self._signal_frame = -1
        self._advance(sim, 0.0)

    def start(self, sim: Simulation) -> None:
        self._signals(sim, force=True)  # after every reset, so a fixed-time reset cannot undo it
        if self.reactive == "always":
            self._hand_to_traffic(sim, self.row[self.state == DRIVING])

    def step(self, sim: Simulation, dt: float) -> None:
        if self.reactive == "interaction":
            self._interactions(sim)
        self._advance(sim, dt)
        self._signals(sim)
        if self.reactive == "always":
            fresh = self.row[(self.state == DRIVING)]
            if fresh.size:
                self._hand_to_traffic(sim, fresh)

    def release(self, sim: Simulation, rows: np.ndarray) -> None:
        rows = np.asarray(rows, dtype=np.int64)
        k = self._vehicle_of_row[rows]
        k = k[k >= 0]
        self.state[k] = DONE
        self.row[k] = -1
        self._vehicle_of_row[rows] = -1

    # ------------------------------------------------------------------ per step
    def frame_at(self, time: float) -> float:
        """The recording's (fractional) frame at simulation time ``time``, on its own clock."""
        return self.recording.frame_of(self.start_time + time)

    def _signals(self, sim: Simulation, force: bool = False) -> None:
        """The recorded signal states of the frame at or before now, written into the simulation's
        signals (those of the map named ``signal_<lane>``; only when the frame changed)."""
        signals = getattr(sim, "signals", None)
        rec = self.recording
        if signals is None or rec.signal_states is None or rec.road_map is None:
            return
        if self._signal_tls is None:
            from smarts.replay.lane_map import SIGNAL_PREFIX

            index = {tls: t for t, tls in enumerate(sim.road_map.tls_ids)}
            self._signal_tls = np.array([index.get(SIGNAL_PREFIX + lane, -1) for lane in rec.road_map.signal_lanes])
        if not (self._signal_tls >= 0).any():  # another map (its own signals, if any, are not recorded ones)
            return
        frame = self.frame_at(sim.time)
        rel = int(np.floor(frame - rec.start_frame + FRAME_EPS))
        rel = min(max(rel, 0), len(rec.signal_states) - 1)
        if rel == self._signal_frame and not force:
            return
        self._signal_frame = rel
        codes = rec.signal_states[rel]
        tls_ids = sim.road_map.tls_ids
        signals.set_states(
            {tls_ids[t]: SIGNAL_CHARS[int(c)] for t, c in zip(self._signal_tls.tolist(), codes) if t >= 0}
        )

    def _advance(self, sim: Simulation, dt: float) -> None:
        rec = self.recording
        frame = self.frame_at(sim.time)
        table = sim.table
        n_enter, n_leave = _advance_tracks(self._tracks, frame, table.data, dt)
        if n_leave:
            leaving = self._leave[:n_leave]
            rows = self.row[leaving]
            self._vehicle_of_row[rows] = -1
            table.remove(rows)
            self.state[leaving] = DONE
            self.row[leaving] = -1
        if n_enter:
            entering = self._enter[:n_enter].copy()
            _, st = interpolate(frame, self.first[entering], self.count[entering], self.offsets[entering],
                                rec.x, rec.y, rec.heading, rec.speed)  # fmt: skip
            for i, k in enumerate(entering.tolist()):
                row = table.add(
                    self.table_ids[k], owner=self.provider_id, role=Role(int(self._role[k])),
                    x=float(st[0, i]), y=float(st[1, i]), heading=float(st[2, i]), speed=float(st[3, i]),
                    vtype=VehicleType(int(self._vtype[k])), length=float(self._dims[0, k]),
                    width=float(self._dims[1, k]),
                )  # fmt: skip
                self.row[k] = row
                self._vehicle_of_row[row] = k
            self.state[entering] = DRIVING

    # ------------------------------------------------------------------ reactive hand-over
    def _interactions(self, sim: Simulation) -> None:
        """Hand every recorded vehicle within ``reactive_distance`` of an agent to traffic, from
        the pose it has now (so it keeps its position, heading and speed)."""
        driving = np.flatnonzero(self.state == DRIVING)
        agents = sim.active_rows
        if driving.size == 0 or agents.size == 0:
            return
        t = sim.table
        rows = self.row[driving]
        dx = t.x[rows][:, None] - t.x[agents][None, :]
        dy = t.y[rows][:, None] - t.y[agents][None, :]
        near = (dx * dx + dy * dy).min(axis=1) <= self.reactive_distance**2
        if near.any():
            self._hand_to_traffic(sim, rows[near])

    def _hand_to_traffic(self, sim: Simulation, rows: np.ndarray) -> None:
        if self.reactive_target is None or rows.size == 0:
            return
        rows = np.asarray(rows, dtype=np.int64)
        rows = rows[self.reactive_target.can_accept(sim, rows)]  # off a lane: it keeps replaying
        if rows.size:
            self.handed_over += [sim.table.ids[r] for r in rows.tolist()]
            sim.hand_over(rows, self.reactive_target, Role.TRAFFIC)


_X, _Y, _H, _V = COLUMN["x"], COLUMN["y"], COLUMN["heading"], COLUMN["speed"]
_ACC, _YAW, _LAT = COLUMN["accel"], COLUMN["yaw_rate"], COLUMN["lat_accel"]


@njit(nogil=True)
def _advance_tracks(tracks, frame, data, dt):  # pragma: no cover - compiled
    """One pass over the window's tracks (a frozen ``Tracks``) at fractional ``frame``: driven
    vehicles get their interpolated state (and the acceleration and yaw rate since the last step)
    written into their table rows of ``data``; vehicles due to enter or leave are listed in
    ``enter``/``leave`` (counts returned) for the caller to add or remove; pending tracks already
    over are marked done. The fields are read once, at the top: the loop writes arrays."""
    tk = view(tracks)
    first, count, offsets, xs, ys, hs, vs = tk.first, tk.count, tk.offsets, tk.x, tk.y, tk.heading, tk.speed
    state, row, enter, leave = tk.state, tk.row, tk.enter, tk.leave
    n_enter, n_leave = 0, 0
    for k in range(first.shape[0]):
        s = state[k]
        if s == DONE:
            continue
        last = count[k] - 1
        rel = frame - first[k]
        present = rel >= -FRAME_EPS and rel <= last + FRAME_EPS
        if s == PENDING:
            if present:
                enter[n_enter] = k
                n_enter += 1
            elif rel > last + FRAME_EPS:
                state[k] = DONE
            continue
        if not present:
            leave[n_leave] = k
            n_leave += 1
            continue
        rel = min(max(rel, 0.0), last)
        k0 = min(int(math.floor(rel + FRAME_EPS)), max(last - 1, 0))
        a = min(max(rel - k0, 0.0), 1.0)
        i0 = offsets[k] + k0
        i1 = min(i0 + 1, offsets[k] + last)
        dh = hs[i1] - hs[i0]
        dh = dh - 2.0 * math.pi * math.floor((dh + math.pi) / (2.0 * math.pi))
        h = wrap_scalar(hs[i0] + dh * a)
        v = vs[i0] + (vs[i1] - vs[i0]) * a
        r = row[k]
        if dt > 0.0:
            yaw = wrap_scalar(h - data[_H, r]) / dt
            data[_ACC, r] = (v - data[_V, r]) / dt
            data[_YAW, r] = yaw
            data[_LAT, r] = yaw * v
        data[_X, r] = xs[i0] + (xs[i1] - xs[i0]) * a
        data[_Y, r] = ys[i0] + (ys[i1] - ys[i0]) * a
        data[_H, r] = h
        data[_V, r] = v
    return n_enter, n_leave
