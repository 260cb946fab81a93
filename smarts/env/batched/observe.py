"""Observations of every agent of a ``BatchedSimulation`` in one compiled call.

The single-episode kernels of ``smarts.sensors.observation`` and ``smarts.core.following`` look
for neighbours among all live rows; here one compiled loop hands each episode's agents and rows
to the same kernels, so episode ``b`` sees exactly what a single simulation of it would see and
no vehicle of another episode.
"""

from __future__ import annotations

import numba
import numpy as np

from smarts.core.batched import BatchedSimulation
from smarts.core.following import LEAD_SIGHT, AheadState, _ahead_kernel
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationBuilder, _observe, lead_features

UNSUPPORTED = ("rasters", "lidar")


def check_interface(interface: AgentInterface) -> None:
    from smarts.env.batched.assembly import BatchedSetupError

    for name in UNSUPPORTED:
        if getattr(interface, name, None) is not None:
            raise BatchedSetupError(f"observation.{name}: not supported by the batched backend; use the per-env backend")
    if interface.needs_shadows or interface.ego.extended:
        what = "occlusion" if interface.needs_shadows else "ego.extended"
        raise BatchedSetupError(f"observation.{what}: not supported by the batched backend; use the per-env backend")


class BatchedObserver:
    """``build(sim, agents)``: the observation dict ``{key: array[len(agents), ...]}`` of union
    agents ``agents`` (ascending), the same arrays ``ObservationBuilder.build`` gives per episode."""

    def __init__(self, interface: AgentInterface):
        check_interface(interface)
        self.builder = ObservationBuilder(interface)
        self.interface = interface
        self.space = self.builder.space

    def build(self, sim: BatchedSimulation, agents: np.ndarray) -> dict[str, np.ndarray]:
        b = self.builder
        interface = self.interface
        ma = sim.mission_arrays
        rows = sim.agent_row[agents]
        obs = b.empty_basic(len(agents))
        alive_lo, alive_hi, agent_lo, agent_hi = sim.episode_ranges(sim.alive, agents)
        _observe_episodes(
            alive_lo, alive_hi, agent_lo, agent_hi, sim.episode_step,
            sim.table.data, sim.table.lane, sim.table.role, sim.table.vtype, sim.alive, agents, rows,
            b._lane_info(sim.road_map), ma.flat_paths, ma.flat_valid, ma.stride,
            sim.route_index, b._offsets, ma.goal_kind, ma.goal_xy, ma.route_length,
            sim.route_progress, ma.signal_via, ma.signal_s, sim.via_colour, sim.agent_events,
            interface.neighbours.radius**2, interface.neighbours.extended, b._no_visible, sim.dt,
            *obs.values(),
        )  # fmt: skip
        if not interface.signals:
            del obs["signal"]
        if interface.lead:
            obs["lead"] = lead_features(sim, agents)
        if interface.ahead:
            st = ahead_state(sim, agents)
            obs["ahead"] = np.stack([st.present, st.gap, st.rel_speed, st.speed, st.accel], axis=1).astype(np.float32)
        return obs


def ahead_state(sim: BatchedSimulation, agents: np.ndarray, sight: float = LEAD_SIGHT) -> AheadState:
    """``smarts.core.following.ahead_state`` of union agents, each among its own episode's rows."""
    n = len(agents)
    out = AheadState(np.zeros(n, bool), np.full(n, float(sight)), np.zeros(n), np.zeros(n), np.zeros(n))
    if n == 0:
        return out
    rm = sim.road_map
    alive_lo, alive_hi, agent_lo, agent_hi = sim.episode_ranges(sim.alive, agents)
    _ahead_episodes(
        alive_lo, alive_hi, agent_lo, agent_hi, sim.table.data, sim.table.lane, sim.agent_row[agents],
        sim.alive, rm.succ_offsets, rm.succ, rm.lane_length, float(sight),
        out.present, out.gap, out.rel_speed, out.speed, out.accel,
    )  # fmt: skip
    return out


@numba.njit(cache=True, nogil=True)
def _ahead_episodes(
    alive_lo, alive_hi, agent_lo, agent_hi, data, lane, rows, alive, succ_offsets, succ, lane_length,
    sight, present, gap, rel_speed, speed, accel,
):  # pragma: no cover - compiled
    for b in range(alive_lo.shape[0]):
        lo, hi = agent_lo[b], agent_hi[b]
        if lo == hi:
            continue
        _ahead_kernel(
            data, lane, rows[lo:hi], alive[alive_lo[b]:alive_hi[b]], succ_offsets, succ, lane_length,
            sight, present[lo:hi], gap[lo:hi], rel_speed[lo:hi], speed[lo:hi], accel[lo:hi],
        )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _observe_episodes(
    alive_lo, alive_hi, agent_lo, agent_hi, episode_step,
    data, lane, role, vtype, alive, agents, rows, lane_info, flat_paths, flat_valid, stride,
    route_index, offsets, goal_kind, goal_xy, route_length, route_progress, signal_via, signal_s,
    via_colour, events, radius2, extended, no_visible, dt,
    ego, neighbours, neighbour_mask, waypoints, waypoint_mask, goal, signal, events_out,
):  # pragma: no cover - compiled
    yaw = np.zeros((3, 1))
    for b in range(alive_lo.shape[0]):
        lo, hi = agent_lo[b], agent_hi[b]
        if lo == hi:
            continue
        _observe(
            data, lane, role, vtype, alive[alive_lo[b]:alive_hi[b]], agents[lo:hi], rows[lo:hi],
            lane_info, flat_paths, flat_valid, stride, route_index, offsets, goal_kind, goal_xy,
            route_length, route_progress, signal_via, signal_s, via_colour[b], events, radius2,
            extended, no_visible, 0, False, yaw, episode_step[b], dt,
            ego[lo:hi], neighbours[lo:hi], neighbour_mask[lo:hi], waypoints[lo:hi],
            waypoint_mask[lo:hi], goal[lo:hi], signal[lo:hi], events_out[lo:hi],
        )  # fmt: skip
