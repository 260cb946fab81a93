"""Traffic-signal state per junction connection, from fixed-time programs or from SUMO.

Every signal-controlled connection (incoming lane -> through the junction -> outgoing lane) has a
colour each step. The built-in traffic model and the red-light rule read ``colour`` and
``stop_xy``; observations read the colours of the connections ahead on a route. The colour comes
either from the map's fixed-time programs (``update_fixed_time``) or from state strings
(``set_states``: SUMO's current states, or a dataset's recorded states for signals without a
program); both give the same per-connection arrays.
"""

from __future__ import annotations

import numpy as np

from smarts.core.provider import ProviderBase
from smarts.maps import RoadMap

NO_SIGNAL, RED, YELLOW, GREEN = 0, 1, 2, 3
_COLOUR_OF_CHAR = {"r": RED, "s": RED, "y": YELLOW, "u": YELLOW, "G": GREEN, "g": GREEN}
"""SUMO link state letters; o/O (off) and anything else count as no signal."""


class SignalState:
    """Colours of the map's signal-controlled connections.

    ``connections`` are indices into the map's ``conn_*`` arrays; ``colour[k]`` is the colour of
    ``connections[k]``; ``via_colour[lane]`` is the colour for entering junction lane ``lane``
    (the first internal lane of a connection; NO_SIGNAL elsewhere); ``lane_colour[lane]`` is the
    most permissive colour of the signalled connections leaving incoming lane ``lane``;
    ``stop_xy[k]`` is where vehicles must stop (the end of the incoming lane).
    """

    def __init__(self, road_map: RoadMap):
        self.road_map = road_map
        self.connections = np.flatnonzero(road_map.conn_tls >= 0)
        self.tls = road_map.conn_tls[self.connections]
        self.link = road_map.conn_link[self.connections]
        self.from_lane = road_map.conn_from[self.connections]
        self.via_lane = road_map.conn_via[self.connections]
        self.colour = np.full(len(self.connections), NO_SIGNAL, dtype=np.int8)
        self.stop_xy = np.array([road_map.lane_polyline(lane)[-1] for lane in self.from_lane]).reshape(-1, 2)
        self.lane_colour = np.zeros(road_map.num_lanes, dtype=np.int8)
        self.via_colour = np.zeros(road_map.num_lanes, dtype=np.int8)
        self._cycle = np.array(
            [
                road_map.tls_phase_duration[a:b].sum()
                for a, b in zip(road_map.tls_phase_offsets[:-1], road_map.tls_phase_offsets[1:])
            ]
        )
        self._last_phase = np.full(len(road_map.tls_ids), -1, dtype=np.int64)

    @property
    def has_signals(self) -> bool:
        return len(self.connections) > 0

    def update_fixed_time(self, time: float) -> None:
        """Colours at ``time`` seconds from the fixed-time programs of the map."""
        rm = self.road_map
        changed = False
        for t in range(len(rm.tls_ids)):
            a, b = rm.tls_phase_offsets[t], rm.tls_phase_offsets[t + 1]
            if b == a:  # no program: a recorded signal, set by whoever replays it (set_states)
                continue
            into = (time + rm.tls_offset[t]) % self._cycle[t]
            phase = a + int(np.searchsorted(np.cumsum(rm.tls_phase_duration[a:b]), into, side="right"))
            phase = min(phase, b - 1)
            if phase != self._last_phase[t]:
                self._last_phase[t] = phase
                self._apply(t, str(rm.tls_phase_state[phase]))
                changed = True
        if changed:
            self._update_lane_colour()

    def set_states(self, states: dict[str, str]) -> None:
        """Colours from SUMO state strings, one per signal id (``trafficlight.getRedYellowGreenState``)."""
        index = {tls_id: t for t, tls_id in enumerate(self.road_map.tls_ids)}
        for tls_id, state in states.items():
            if tls_id in index:
                self._apply(index[tls_id], state)
        self._update_lane_colour()

    def _apply(self, tls: int, state: str) -> None:
        mine = self.tls == tls
        links = self.link[mine]
        self.colour[mine] = [
            _COLOUR_OF_CHAR.get(state[k], NO_SIGNAL) if 0 <= k < len(state) else NO_SIGNAL for k in links
        ]

    def _update_lane_colour(self) -> None:
        self.lane_colour[:] = NO_SIGNAL
        np.maximum.at(self.lane_colour, self.from_lane, self.colour)
        has_via = self.via_lane >= 0
        self.via_colour[self.via_lane[has_via]] = self.colour[has_via]


class FixedTimeSignals(ProviderBase):
    """A provider that runs the map's fixed-time programs (used when SUMO does not run)."""

    name = "signals"

    def __init__(self, signals: SignalState):
        self.signals = signals

    def reset(self, sim) -> None:
        self.signals._last_phase[:] = -1
        self.signals.update_fixed_time(0.0)

    def step(self, sim, dt: float) -> None:
        self.signals.update_fixed_time(sim.time)
