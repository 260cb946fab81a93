"""Memory growth of the SUMO provider over many resets.

``python -m smarts.diagnostic.reset_memory [--resets 1000] [--steps 5]`` resets a scenario with
medium-density SUMO traffic on a 4-way intersection again and again (a few steps each) and prints
the process's resident memory after a warm-up and at the end. Each reset reloads the one libsumo
simulation of the process (``simulation.load``), so growth here is what a long training run would
accumulate.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

WARMUP_RESETS = 10
"""Resets before the first reading: caches (map, compiled kernels, SUMO's router) fill up."""


def resident_mb() -> float:
    """Current resident set size of this process in MB (Linux ``/proc``; peak RSS elsewhere)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0)


def measure(resets: int = 1000, steps: int = 5, density: str = "medium") -> dict:
    """Reset ``resets`` times with ``steps`` steps each; returns RSS readings in MB."""
    from smarts.env.assembly import build_simulation
    from smarts.scenario import read_scenario

    spec = read_scenario(
        {
            "name": "reset_memory",
            "map": "builtin:intersection_4way_1lane_signal",
            "agents": [
                {
                    "action_space": "relative_target_pose",
                    "mission": {
                        "start": {"road": "west_in", "lane": 0, "offset": 30.0, "speed": 5.0},
                        "goal": {"endless": True},
                    },
                }
            ],
            "traffic": {"engine": "sumo", "density": density},
        },
        source="reset-memory",
    )
    sim = build_simulation(spec)  # engine: sumo, so the assembly adds SUMO and its signals
    actions = {a: np.array([0.5, 0.0, 0.0]) for a in sim.agent_ids}
    try:
        for seed in range(WARMUP_RESETS):
            _episode(sim, seed, steps, actions)
        start = resident_mb()
        t0 = time.perf_counter()
        for seed in range(WARMUP_RESETS, WARMUP_RESETS + resets):
            _episode(sim, seed, steps, actions)
        seconds = time.perf_counter() - t0
        end = resident_mb()
    finally:
        sim.close()
    return {
        "resets": resets,
        "steps": steps,
        "start_mb": start,
        "end_mb": end,
        "growth_mb": end - start,
        "ms_per_reset": 1e3 * seconds / max(resets, 1),
    }


def _episode(sim, seed: int, steps: int, actions) -> None:
    sim.reset(seed=seed)
    for _ in range(steps):
        sim.step(actions)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m smarts.diagnostic.reset_memory", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--resets", type=int, default=1000, help="resets to measure (default 1000)")
    parser.add_argument("--steps", type=int, default=5, help="steps after each reset (default 5)")
    parser.add_argument("--density", default="medium", help="traffic density (default medium)")
    args = parser.parse_args(argv)
    r = measure(args.resets, args.steps, args.density)
    print(f"RSS after {WARMUP_RESETS} warm-up resets: {r['start_mb']:.1f} MB")
    print(f"RSS after {r['resets']} more resets ({r['steps']} steps each): {r['end_mb']:.1f} MB")
    print(
        f"growth: {r['growth_mb']:.2f} MB ({1024 * r['growth_mb'] / max(r['resets'], 1):.2f} kB per "
        f"reset); {r['ms_per_reset']:.1f} ms per reset with its steps"
    )


if __name__ == "__main__":
    main()
