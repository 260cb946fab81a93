"""The replay provider: recorded vehicles follow their tracks, interpolated to the simulation step.

Each step looks every recorded vehicle of the window up at once (``Recording.state_at`` on arrays):
vehicles whose track starts by now enter the vehicle table, those whose track has ended leave it,
and the rest get their interpolated pose and speed written into their rows. A row handed to another
provider (an agent taking a vehicle over, or the traffic model when the vehicle turns reactive) is
released for good: its recording is no longer replayed.

Reactive hand-over goes through the simulation's ``hand_over`` to a provider the env assembles
(``reactive_target``, the built-in traffic model); this package never imports traffic.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from smarts.core.provider import ProviderBase
from smarts.core.vehicle_table import Role, VehicleType
from smarts.replay.recording import FRAME_EPS, Recording, interpolate, wrap_angle

if TYPE_CHECKING:
    from smarts.core.provider import Provider
    from smarts.core.simulation import Simulation

ID_PREFIX = "replay-"
"""Vehicle table ids of recorded vehicles are this prefix and the dataset's id."""

PENDING, DRIVING, DONE = 0, 1, 2


def table_id(vehicle_id: str) -> str:
    return f"{ID_PREFIX}{vehicle_id}"


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
        self.start_frame = recording.start_frame + start / recording.dt
        self.end_frame = np.inf if duration is None else self.start_frame + duration / recording.dt
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
        self.handed_over: list[str] = []
        """Table ids of the vehicles handed to the traffic model this episode, in order."""

    # ------------------------------------------------------------------ episode
    def reset(self, sim: Simulation) -> None:
        self.state[:] = PENDING
        self.row[:] = -1
        self._vehicle_of_row = np.full(sim.table.capacity, -1, dtype=np.int64)
        self.handed_over = []
        self._advance(sim, 0.0)

    def start(self, sim: Simulation) -> None:
        if self.reactive == "always":
            self._hand_to_traffic(sim, self.row[self.state == DRIVING])

    def step(self, sim: Simulation, dt: float) -> None:
        if self.reactive == "interaction":
            self._interactions(sim)
        self._advance(sim, dt)
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
        """The recording's (fractional) frame at simulation time ``time``."""
        return self.start_frame + time / self.recording.dt

    def _advance(self, sim: Simulation, dt: float) -> None:
        rec = self.recording
        frame = self.frame_at(sim.time)
        present, st = interpolate(frame, self.first, self.count, self.offsets, rec.x, rec.y, rec.heading, rec.speed)
        table = sim.table
        leaving = np.flatnonzero((self.state == DRIVING) & ~present)
        if leaving.size:
            rows = self.row[leaving]
            self._vehicle_of_row[rows] = -1
            table.remove(rows)
            self.state[leaving] = DONE
            self.row[leaving] = -1
        # a pending vehicle whose track ended before it could enter never will
        self.state[(self.state == PENDING) & (frame > self.first + self.count - 1 + FRAME_EPS)] = DONE
        entering = np.flatnonzero((self.state == PENDING) & present)
        for k in entering.tolist():
            row = table.add(
                self.table_ids[k], owner=self.provider_id, role=Role.REPLAY,
                x=float(st[0, k]), y=float(st[1, k]), heading=float(st[2, k]), speed=float(st[3, k]),
                vtype=VehicleType(int(self._vtype[k])), length=float(self._dims[0, k]), width=float(self._dims[1, k]),
            )  # fmt: skip
            self.row[k] = row
            self._vehicle_of_row[row] = k
        self.state[entering] = DRIVING
        driving = np.flatnonzero(self.state == DRIVING)
        if driving.size == 0:
            return
        rows = self.row[driving]
        moved = np.setdiff1d(driving, entering, assume_unique=True) if entering.size else driving
        if dt > 0 and moved.size:
            r = self.row[moved]
            table.accel[r] = (st[3, moved] - table.speed[r]) / dt
            table.yaw_rate[r] = wrap_angle(st[2, moved] - table.heading[r]) / dt
            table.lat_accel[r] = table.yaw_rate[r] * st[3, moved]
        table.x[rows] = st[0, driving]
        table.y[rows] = st[1, driving]
        table.heading[rows] = st[2, driving]
        table.speed[rows] = st[3, driving]

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
