"""Cost of a simulation step with N SUMO vehicles (the SUMO rows of ``python -m smarts.diagnostic``;
``python -m smarts.diagnostic.sumo_step`` prints 1, 10, 20, 50 and 200 vehicles on its own).

Same set-up as SMARTS's ``n_sumo_actors`` diagnostic: the 455 m 6-lane highway (its 1.28 km
version for more than 50 vehicles, which the short road cannot hold), 5 flows at 3600 vehicles
per hour that end after N/5 s (1 flow of 1 vehicle for N = 1). The clock starts once N vehicles
are on the road (or the flows have ended and the count stopped growing). One stopped
agent waits on the on-ramp, because a simulation needs an agent; its SUMO twin costs one
``moveToXY`` per step.
"""

from __future__ import annotations

import time

import numpy as np

from smarts.core.spec import replace
from smarts.core.spec.traffic import FlowSpec, TrafficSpec
from smarts.core.vehicle_table import Role
from smarts.scenario import ScenarioSpec, read_scenario
from smarts.traffic.sumo_provider import SumoTrafficProvider

BENCHMARK_MAP = "highway_6lane_ramp"
LONG_BENCHMARK_MAP = "highway_6lane_ramp_long"
LONG_MAP_ABOVE = 50
"""Vehicle counts above this run on the long highway."""


def benchmark_traffic(n_vehicles: int) -> TrafficSpec:
    if n_vehicles <= 1:
        flows = [FlowSpec("f0", route=["main_0", "main_2"], rate=1.0, depart_lane=0)]
    else:
        end = max(n_vehicles / 5.0, 0.1)
        flows = [
            FlowSpec(
                f"f{k}",
                route=["main_0", "main_2"],
                rate=3600.0,
                end=end,
                depart_lane=k,
                depart_speed="max",
            )
            for k in range(5)
        ]
    return TrafficSpec(engine="sumo", flows=flows)


def benchmark_spec(n_vehicles: int, seed: int = 42) -> ScenarioSpec:
    """The scenario without its traffic: the highway (the long one above ``LONG_MAP_ABOVE``
    vehicles) and one stopped agent on the on-ramp."""
    agent = {
        "action_space": "relative_target_pose",
        "mission": {"start": {"road": "ramp", "lane": 0, "offset": 5.0, "speed": 0.0}, "goal": {"endless": True}},
    }
    road = LONG_BENCHMARK_MAP if n_vehicles > LONG_MAP_ABOVE else BENCHMARK_MAP
    return read_scenario(
        {
            "name": f"sumo_benchmark_{n_vehicles}",
            "map": f"builtin:{road}",
            "seed": seed,
            "vehicle_capacity": max(256, 2 * n_vehicles),
            "agents": [agent],
        },
        source="sumo-benchmark",
    )


def sumo_step_benchmark(n_vehicles: int, steps: int = 200, seed: int = 42) -> dict:
    """Run the scenario and time ``steps`` steps once ``n_vehicles`` SUMO vehicles exist.

    Returns ``{"n_vehicles", "vehicles" (mean count while timed), "steps", "step_ms" (median whole
    simulation step), "sumo_ms" (median of the SUMO provider's part), "sumo_ms_mean", "warmup_steps"}``.
    """
    from smarts.env.assembly import build_simulation

    spec = benchmark_spec(n_vehicles, seed)
    sim = build_simulation(replace(spec, traffic=benchmark_traffic(n_vehicles)))
    (provider,) = [p for p in sim.providers if isinstance(p, SumoTrafficProvider)]
    sumo_times: list[float] = []
    step = provider.step

    def timed_step(s, dt):
        t0 = time.perf_counter()
        step(s, dt)
        sumo_times.append(time.perf_counter() - t0)

    provider.step = timed_step
    try:
        sim.reset()
        actions = {a: np.zeros(3) for a in sim.agent_ids}
        table = sim.table
        warmup, best, stalled = 0, 0, 0
        flows_end = max(n_vehicles / 5.0, 0.1) + 2.0
        while True:
            count = int(np.count_nonzero(table.alive & (table.role == int(Role.TRAFFIC))))
            if count >= n_vehicles:
                break
            stalled = stalled + 1 if count <= best else 0
            best = max(best, count)
            if sim.time > flows_end and stalled > 20:
                break  # the road holds fewer vehicles than asked for: time what it has
            sim.step(actions)
            warmup += 1
        sumo_times.clear()
        whole, counts = [], []
        for _ in range(steps):
            t0 = time.perf_counter()
            sim.step(actions)
            whole.append(time.perf_counter() - t0)
            counts.append(int(np.count_nonzero(table.alive & (table.role == int(Role.TRAFFIC)))))
    finally:
        sim.close()
    return {
        "n_vehicles": n_vehicles,
        "vehicles": float(np.mean(counts)),
        "steps": steps,
        "step_ms": 1e3 * float(np.median(whole)),
        "sumo_ms": 1e3 * float(np.median(sumo_times)),
        "sumo_ms_mean": 1e3 * float(np.mean(sumo_times)),
        "warmup_steps": warmup,
    }


if __name__ == "__main__":
    for n in (1, 10, 20, 50, 200):
        r = sumo_step_benchmark(n)
        print(
            f"{n:4d} vehicles asked, {r['vehicles']:6.1f} timed: step {r['step_ms']:.3f} ms, "
            f"SUMO provider {r['sumo_ms']:.3f} ms (median)"
        )
