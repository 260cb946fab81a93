"""Step timing of dataset replay (the replay rows of ``python -m smarts.diagnostic``).

Like SMARTS's diagnostic replay cases: ``n`` recorded vehicles drive along the six lanes of the
455 m highway (an NGSIM trajectory CSV written here in the published layout, 0.1 s frames, read
back through the real reader), all of them present for every timed step. Timed: the replay
provider's own step and the whole simulation step (providers, map projection of every vehicle,
events, route progress), with one agent on the road; in the take-over case that agent drives one of
the recorded vehicles (its first state, its goal at the track's end) while the others replay.
"""

from __future__ import annotations

import csv
import tempfile
import time
from pathlib import Path

import numpy as np

BENCH_MAP = "highway_6lane_ramp"
LANE_Y = (-20.13, -16.47, -12.81, -9.15, -5.49, -1.83)
"""Centre lines of the highway's six main lanes (metres, along +x)."""
SPEED = 8.0  # m/s
SPACING = 12.0  # m between vehicles in a lane
FIRST_X = 20.0
FEET = 0.3048


def write_bench_csv(path: Path, n_vehicles: int, frames: int, seed: int = 0) -> Path:
    """An NGSIM CSV of ``n_vehicles`` cruising at ``SPEED`` in rows across the six lanes, each
    recorded for ``frames`` frames (Local_Y along the road, Local_X across it, feet, front edge)."""
    rng = np.random.default_rng(seed)
    header = ["Vehicle_ID", "Frame_ID", "Total_Frames", "Local_X", "Local_Y", "v_Length", "v_Width", "v_Class", "v_Vel"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for v in range(n_vehicles):
            lane, slot = v % len(LANE_Y), v // len(LANE_Y)
            x0 = FIRST_X + SPACING * slot
            speed = SPEED + rng.uniform(-0.3, 0.3)
            k = np.arange(frames)
            front = x0 + 2.25 + speed * 0.1 * k + rng.normal(0.0, 0.03, frames)
            lateral = -LANE_Y[lane] + rng.normal(0.0, 0.03, frames)
            for i in range(frames):
                w.writerow([v + 1, 1000 + i, frames, f"{lateral[i] / FEET:.3f}", f"{front[i] / FEET:.3f}",
                            f"{4.5 / FEET:.2f}", f"{1.8 / FEET:.2f}", 2, f"{speed / FEET:.2f}"])  # fmt: skip
    return path


def replay_step_benchmark(n_vehicles: int, steps: int = 300, warmup: int = 20, take_over: bool = False) -> dict:
    """Time ``steps`` simulation steps with ``n_vehicles`` replayed (one taken over if asked).

    Returns milliseconds per step (median and mean) of the replay provider and of the whole
    simulation step, and the replayed vehicle count while timing."""
    from smarts.env.assembly import build_simulation
    from smarts.scenario import ScenarioSpec

    frames = steps + warmup + 5
    with tempfile.TemporaryDirectory(prefix="smarts-replay-bench-") as folder:
        csv_path = write_bench_csv(Path(folder) / "bench.csv", n_vehicles, frames)
        if take_over:
            agent = {"id": "ego", "action_space": "relative_target_pose"}
        else:
            # stands at the far end of the ramp, out of everyone's way
            agent = {"id": "ego", "mission": {"start": {"road": "ramp", "lane": 0, "offset": 5.0}, "goal": {"endless": True}}}
        replay = {"format": "ngsim", "path": str(csv_path), "swap_xy": True, "flip_y": True}
        if take_over:
            replay["take_over"] = {"ego": str(n_vehicles)}  # the front vehicle of its lane
        spec = ScenarioSpec.from_dict(
            {"name": f"replay_{n_vehicles}", "map": f"builtin:{BENCH_MAP}", "episode_steps": frames,
             "vehicle_capacity": n_vehicles + 8, "events": {"terminate_on": []}, "replay": replay, "agents": [agent]},
            source="replay_step_benchmark",
        )  # fmt: skip
        sim = build_simulation(spec)
    provider = next(p for p in sim.providers if p.name == "replay")
    sim.reset()
    row = int(sim.agent_row[0])
    step_dx = np.array([SPEED * sim.dt, 0.0, 0.0])
    zero = np.zeros(3)

    def actions() -> dict:
        return {"ego": step_dx if take_over else zero}

    provider_ms, sim_ms, counts = [], [], []
    inner = provider.step

    def timed_step(s, dt):
        t0 = time.perf_counter()
        inner(s, dt)
        provider_ms.append((time.perf_counter() - t0) * 1e3)

    for _ in range(warmup):
        sim.step(actions())
    provider.step = timed_step
    try:
        for _ in range(steps):
            t0 = time.perf_counter()
            sim.step(actions())
            sim_ms.append((time.perf_counter() - t0) * 1e3)
            counts.append(int((provider.state == 1).sum()))
    finally:
        del provider.step
    return {
        "n_vehicles": int(n_vehicles),
        "take_over": bool(take_over),
        "replayed_min": int(min(counts)),
        "replayed_mean": float(np.mean(counts)),
        "agent_on_road": bool(sim.table.alive[row]),
        "provider_ms_median": float(np.median(provider_ms)),
        "provider_ms_mean": float(np.mean(provider_ms)),
        "sim_step_ms_median": float(np.median(sim_ms)),
        "sim_step_ms_mean": float(np.mean(sim_ms)),
        "sim_step_ms_p90": float(np.percentile(sim_ms, 90)),
        "steps": int(steps),
    }
