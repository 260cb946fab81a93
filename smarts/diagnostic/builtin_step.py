"""Step timing of the built-in traffic model at a given number of vehicles (the built-in rows of
``python -m smarts.diagnostic``).

Like SMARTS's diagnostic "n local actors" case: five flows of 3600 vehicles per hour enter the
six-lane highway until ``n_vehicles`` are on it (slow, closely following vehicles, so that many
fit on the road); then departures stop and ``steps`` steps are timed, both the traffic
provider's own step and the whole simulation step (provider, map projection of every vehicle,
events and route progress).
"""

from __future__ import annotations

import time

import numpy as np

from smarts.core.spec.traffic import FlowSpec, TrafficSpec, VehicleTypeSpec

BENCH_MAP = "highway_6lane_ramp"
BENCH_FLOWS = 5
BENCH_RATE = 3600.0  # vehicles per hour per flow
BENCH_SPEED = 3.0
"""m/s, with a 0.5 s headway: slow and close enough that the vehicles the entry admits add up to
200 on the 455 m road (SMARTS used a 1.28 km road for that many at highway speed)."""
MAX_FILL_STEPS = 5000


def builtin_step_benchmark(n_vehicles: int, steps: int = 200, seed: int = 42) -> dict:
    """Fill the highway with ``n_vehicles`` and time ``steps`` steps.

    Returns milliseconds per step (median and mean) for the provider and the whole simulation
    step, and the vehicle count while timing.
    """
    from smarts.env.assembly import build_simulation
    from smarts.scenario import read_scenario
    from smarts.traffic.builtin.provider import BuiltinTrafficProvider

    spec = read_scenario(
        {
            "name": f"builtin_traffic_{n_vehicles}",
            "map": f"builtin:{BENCH_MAP}",
            "vehicle_capacity": int(n_vehicles) + 64,
            "seed": seed,
            "agents": [
                # Only there because a simulation starts with an agent; it leaves right away.
                {
                    "id": "placeholder",
                    "mission": {"start": {"road": "ramp", "lane": 0, "offset": 5.0}, "goal": {"endless": True}},
                },
            ],
        },
        source="builtin_step_benchmark",
    )
    sim = build_simulation(spec)
    flows = [
        FlowSpec(id=f"flow_{i}", route=["main_0", "main_2"], rate=BENCH_RATE, depart_lane=i, vehicle_type="bench")
        for i in range(BENCH_FLOWS)
    ]
    bench = VehicleTypeSpec("bench", max_speed=BENCH_SPEED, tau=0.5, min_gap=2.0, speed_dev=0.0)
    traffic = TrafficSpec(vehicle_types={"bench": bench}, flows=flows)
    provider = BuiltinTrafficProvider(traffic, sim.road_map, sim.dt)
    sim.add_provider(provider)
    sim.reset()
    sim.agent_done[:] = True
    sim.remove_done_agents()
    fill = 0
    while provider.mine.sum() < n_vehicles and fill < MAX_FILL_STEPS:
        sim.step({})
        fill += 1
    provider.next_time[:] = np.inf  # no more departures: time the step at n_vehicles
    provider.pending[:] = 0

    provider_ms, sim_ms, counts = [], [], []
    (stage,) = sim.batch_stages  # the built-in traffic's step (the provider's batch stage)
    inner = stage.step

    def timed_step(s, dt):
        t0 = time.perf_counter()
        inner(s, dt)
        provider_ms.append((time.perf_counter() - t0) * 1e3)

    stage.step = timed_step
    try:
        for _ in range(steps):
            counts.append(int(provider.mine.sum()))
            t0 = time.perf_counter()
            sim.step({})
            sim_ms.append((time.perf_counter() - t0) * 1e3)
    finally:
        del stage.step
    return {
        "n_vehicles": int(n_vehicles),
        "fill_steps": fill,
        "vehicles_min": int(min(counts)),
        "vehicles_mean": float(np.mean(counts)),
        "provider_ms_median": float(np.median(provider_ms)),
        "provider_ms_mean": float(np.mean(provider_ms)),
        "sim_step_ms_median": float(np.median(sim_ms)),
        "sim_step_ms_mean": float(np.mean(sim_ms)),
        "steps": int(steps),
    }
