"""Simulations with the built-in traffic provider on the project's maps, for the builtin tests."""

from __future__ import annotations

import numpy as np

from smarts.core.events import box_collisions
from smarts.core.spec.traffic import TrafficSpec
from smarts.env.assembly import build_simulation
from smarts.traffic.builtin import BuiltinTrafficProvider
from smarts.traffic.signals import FixedTimeSignals, SignalState
from tests.builders import agent, make_spec

STILL = np.zeros(3)  # RelativeTargetPose: stay where you are


def traffic_sim(
    map_name: str,
    traffic: TrafficSpec,
    agent_road: str,
    *,
    keep_agent: bool = False,
    signals: bool = False,
    seed: int = 42,
    capacity: int = 256,
    **agent_kw,
):
    """(simulation, provider) after reset. A simulation starts with an agent: it stands on
    ``agent_road`` and, unless ``keep_agent``, leaves right after the reset. ``signals``: the
    traffic obeys the map's fixed-time signal programs."""
    spec = make_spec([agent(agent_road, **agent_kw)], map_name=map_name, seed=seed, vehicle_capacity=capacity)
    sim = build_simulation(spec)
    state = getattr(sim, "signals", None)  # the assembly may already run the map's signals
    if signals and state is None:
        state = SignalState(sim.road_map)
        sim.add_provider(FixedTimeSignals(state))
    provider = BuiltinTrafficProvider(traffic, sim.road_map, sim.dt, state if signals else None)
    sim.add_provider(provider)
    sim.reset()
    if not keep_agent:
        sim.agent_done[:] = True
        sim.remove_done_agents()
    return sim, provider


def step(sim, n: int = 1) -> None:
    for _ in range(n):
        sim.step({a: STILL for i, a in enumerate(sim.agent_ids) if sim.agent_active[i]})


def traffic_rows(provider) -> np.ndarray:
    return np.flatnonzero(provider.mine)


def overlapping(sim, rows: np.ndarray) -> np.ndarray:
    """Which of ``rows`` overlap another of them (oriented boxes)."""
    t = sim.table
    radius = 0.5 * np.hypot(t.length[rows], t.width[rows])
    return box_collisions(t.corners(rows), t.x[rows], t.y[rows], radius)


def front_to_lane_end(sim, row: int) -> float:
    """Metres from the front bumper to the end of the row's current lane (negative past it)."""
    t = sim.table
    lane = t.lane[row]
    return float(sim.road_map.lane_length[lane] - t.s[row] - 0.5 * t.length[row])
