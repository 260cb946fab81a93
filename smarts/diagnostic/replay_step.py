"""Step timing of dataset replay (the replay rows of ``python -m smarts.diagnostic``).

Like SMARTS's diagnostic replay cases: ``n`` recorded vehicles drive along the six lanes of the
455 m highway (an NGSIM trajectory CSV written here in the published layout, 0.1 s frames, read
back through the real reader), all of them present for every timed step. Timed: the whole
PettingZoo step (simulation, the agent's observation with its neighbours, reward), the simulation
step alone (providers, map projection of every vehicle, events, route progress) and the replay
provider's own step, with one agent on the road; in the take-over case that agent drives one of
the recorded vehicles (its first state, its goal at the track's end) while the others replay. The
reference row (0) is the same agent with no replay.
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
    """Time ``steps`` PettingZoo steps with ``n_vehicles`` replayed (one taken over if asked; 0: no
    replay at all, the reference row).

    Returns milliseconds per step (median with a bootstrap 95% interval, mean, 90th percentile) of
    the whole env step (simulation, the agent's observation, reward), of the simulation step alone
    and of the replay provider, and the replayed vehicle count while timing."""
    from smarts.env import DrivingParallelEnv
    from smarts.scenario import read_scenario

    frames = steps + warmup + 5
    with tempfile.TemporaryDirectory(prefix="smarts-replay-bench-") as folder:
        data = {"name": f"replay_{n_vehicles}", "map": f"builtin:{BENCH_MAP}", "episode_steps": frames,
                "vehicle_capacity": n_vehicles + 8, "events": {"terminate_on": []}}  # fmt: skip
        # the agent stands at the far end of the ramp, out of everyone's way, unless it takes over
        agent = {
            "id": "ego",
            "mission": {"start": {"road": "ramp", "lane": 0, "offset": 5.0}, "goal": {"endless": True}},
        }
        if n_vehicles:
            csv_path = write_bench_csv(Path(folder) / "bench.csv", n_vehicles, frames)
            data["replay"] = {"format": "ngsim", "path": str(csv_path), "swap_xy": True, "flip_y": True}
            if take_over:
                data["replay"]["take_over"] = {"ego": str(n_vehicles)}  # the front vehicle of its lane
                agent = {"id": "ego"}
        data["agents"] = [agent]
        env = DrivingParallelEnv(read_scenario(data, source="replay_step_benchmark"))
        env.reset(seed=0)
    sim = env.sim
    provider = next((p for p in sim.providers if p.name == "replay"), None)
    row = int(sim.agent_row[0])
    action = np.array([SPEED * sim.dt, 0.0, 0.0] if take_over else [0.0, 0.0, 0.0], dtype=np.float32)

    provider_ms, sim_ms, env_ms, counts = [], [], [], []
    inner_provider, inner_sim = (provider.step if provider else None), sim.step

    def timed_provider(s, dt):
        t0 = time.perf_counter()
        inner_provider(s, dt)
        provider_ms.append((time.perf_counter() - t0) * 1e3)

    def timed_sim(actions):
        t0 = time.perf_counter()
        inner_sim(actions)
        sim_ms.append((time.perf_counter() - t0) * 1e3)

    try:
        for _ in range(warmup):
            env.step({"ego": action})
        if provider is not None:
            provider.step = timed_provider
        sim.step = timed_sim
        for _ in range(steps):
            t0 = time.perf_counter()
            env.step({"ego": action})
            env_ms.append((time.perf_counter() - t0) * 1e3)
            counts.append(int((provider.state == 1).sum()) if provider is not None else 0)
    finally:
        if provider is not None:
            del provider.step
        del sim.step
        env.close()
    lo, hi = median_interval(np.array(env_ms))
    return {
        "n_vehicles": int(n_vehicles),
        "take_over": bool(take_over),
        "replayed_min": int(min(counts)),
        "replayed_mean": float(np.mean(counts)),
        "agent_on_road": bool(sim.table.alive[row]),
        "env_step_ms_median": float(np.median(env_ms)),
        "env_step_ms_median_ci95": [lo, hi],
        "env_step_ms_mean": float(np.mean(env_ms)),
        "env_step_ms_p90": float(np.percentile(env_ms, 90)),
        "sim_step_ms_median": float(np.median(sim_ms)),
        "provider_ms_median": float(np.median(provider_ms)) if provider_ms else 0.0,
        "steps": int(steps),
    }


def median_interval(samples: np.ndarray, resamples: int = 1000, seed: int = 0) -> tuple[float, float]:
    """Bootstrap 95% interval of the median of ``samples``."""
    rng = np.random.default_rng(seed)
    medians = np.median(rng.choice(samples, size=(resamples, samples.size), replace=True), axis=1)
    return float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))
