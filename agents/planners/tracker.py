"""Stable ids for observed neighbours, and their histories in the odometry frame.

Observations list the nearest road users without ids. AID needs 1 s histories per road user, so
the tracker associates each step's neighbours to the previous step's tracks: predict every track
at constant velocity, then greedily match nearest pairs within a distance gate and a heading gate.
A track that goes unseen (occluded, out of range, pushed out of the K nearest) is coasted at
constant velocity for up to ``max_missed`` steps and picks up its id again when it reappears.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agents.obs_columns import NEIGHBOUR_XY, Neighbour
from agents.planners.frames import local_to_global, rotation, wrap

STATE = ("x", "y", "heading", "speed", "vx", "vy")
"""Columns of a track state (odometry frame; velocity as a world vector)."""


@dataclass
class Track:
    id: int
    states: dict[int, np.ndarray] = field(default_factory=dict)  # frame -> state [6]
    length: float = 4.6
    width: float = 1.9
    last_frame: int = 0

    @property
    def last(self) -> np.ndarray:
        return self.states[self.last_frame]


class NeighbourTracker:
    """Per agent: ``update`` once per step with the odometry pose and the observed neighbours."""

    def __init__(self, gate: float = 2.5, heading_gate: float = np.pi / 4, max_missed: int = 10,
                 keep: int = 11, dt: float = 0.1):  # fmt: skip
        self.gate, self.heading_gate, self.max_missed, self.keep, self.dt = gate, heading_gate, max_missed, keep, dt
        self.tracks: dict[int, Track] = {}
        self.frame = -1
        self._next_id = 0

    @staticmethod
    def observed_states(pose: np.ndarray, ego_speed: float, neighbours: np.ndarray) -> np.ndarray:
        """Neighbour rows [K, >=8] of the ego observation -> odometry-frame states [K, 6]."""
        nb = np.asarray(neighbours, dtype=np.float64)
        xy = local_to_global(nb[:, NEIGHBOUR_XY], pose)
        heading = wrap(pose[2] + np.arctan2(nb[:, Neighbour.SIN_HEADING], nb[:, Neighbour.COS_HEADING]))
        vel = np.stack([nb[:, Neighbour.VX] + ego_speed, nb[:, Neighbour.VY]], axis=1) @ rotation(pose[2]).T
        speed = np.linalg.norm(vel, axis=1)
        return np.column_stack([xy, heading, speed, vel])

    def update(self, pose: np.ndarray, ego_speed: float, neighbours: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Associate this step's neighbours with tracks; returns the track id of each row (-1 where
        the mask is 0)."""
        self.frame += 1
        present = np.flatnonzero(np.asarray(mask) > 0)
        ids = np.full(len(mask), -1, dtype=np.int64)
        states = (
            self.observed_states(pose, ego_speed, np.asarray(neighbours)[present]) if present.size else np.zeros((0, 6))
        )
        live = list(self.tracks.values())
        pairs: list[tuple[float, int, int]] = []
        for ti, track in enumerate(live):
            gap = self.frame - track.last_frame
            last = track.last
            predicted = last[:2] + last[4:6] * self.dt * gap
            dist = np.linalg.norm(states[:, :2] - predicted, axis=1) if len(states) else np.zeros(0)
            dh = np.abs(wrap(states[:, 2] - last[2])) if len(states) else np.zeros(0)
            gate = self.gate * (1.0 + 0.5 * (gap - 1))  # coasted tracks get a wider gate
            for di in np.flatnonzero((dist < gate) & ((dh < self.heading_gate) | (states[:, 3] < 0.5))):
                pairs.append((float(dist[di]), ti, int(di)))
        used_t: set[int] = set()
        used_d: set[int] = set()
        for _, ti, di in sorted(pairs):
            if ti in used_t or di in used_d:
                continue
            used_t.add(ti)
            used_d.add(di)
            self._record(live[ti], states[di], neighbours[present[di]])
            ids[present[di]] = live[ti].id
        for di in range(len(states)):
            if di not in used_d:
                track = Track(self._next_id)
                self._next_id += 1
                self.tracks[track.id] = track
                self._record(track, states[di], neighbours[present[di]])
                ids[present[di]] = track.id
        for track in list(self.tracks.values()):
            if self.frame - track.last_frame > self.max_missed:
                del self.tracks[track.id]
        return ids

    def _record(self, track: Track, state: np.ndarray, row: np.ndarray) -> None:
        track.states[self.frame] = state
        track.last_frame = self.frame
        track.length, track.width = float(row[Neighbour.LENGTH]), float(row[Neighbour.WIDTH])
        for old in [f for f in track.states if f <= self.frame - self.keep]:
            del track.states[old]

    def history(self, track_id: int, steps: int = 11) -> np.ndarray:
        """States [steps, 6] of frames frame-steps+1 .. frame (oldest first); rows before the most
        recent gap (and unseen frames) are zero."""
        out = np.zeros((steps, 6))
        track = self.tracks[track_id]
        for i in range(steps):
            f = self.frame - i
            if f not in track.states:
                break
            out[steps - 1 - i] = track.states[f]
        return out
