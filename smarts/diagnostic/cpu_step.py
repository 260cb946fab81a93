"""CPU time per step of the two cases where fixed costs dominate (the CPU rows of ``python -m
smarts.diagnostic``; ``--stages`` splits them by stage).

- ``one_agent``: one RelativeTargetPose agent cruising on the six-lane highway with the default
  observation, timed over whole PettingZoo ``step`` calls.
- ``sumo``: the SUMO traffic case of ``smarts.diagnostic.sumo_step`` (N flow vehicles, one
  placeholder agent), timed over whole simulation steps once N vehicles are on the road.

Times are the thread's CPU time (``time.thread_time_ns``), not wall time, so other jobs on a shared
machine slow them less. The stage split wraps the step's parts by name where they exist (so the
same split runs on older trees); the wrappers add their own cost, so the stages of a split run sum
to more than a plain run's step.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from smarts.core.spec import replace

SETTLE_METHODS = ("_settle", "_project", "_route_progress_of", "_events_of")
"""The simulation's map projection, route progress and events (fused into ``_settle`` or not)."""


class StageTimer:
    """Adds the thread CPU time of wrapped calls to named stages (nested calls count in both)."""

    def __init__(self) -> None:
        self.ns: dict[str, int] = defaultdict(int)

    def wrap(self, owner: object, name: str, stage: str) -> None:
        """Time ``owner.<name>`` (an attribute on an instance or module) under ``stage``."""
        if not hasattr(owner, name):
            return
        inner = getattr(owner, name)
        clock, ns = time.thread_time_ns, self.ns

        def timed(*args, **kwargs):
            t0 = clock()
            try:
                return inner(*args, **kwargs)
            finally:
                ns[stage] += clock() - t0

        setattr(owner, name, timed)

    def per_step_us(self, steps: int, total_ns: int, order: list[str]) -> dict[str, float]:
        """Microseconds per step of each stage in ``order``, the rest as ``other``."""
        out = {s: self.ns.get(s, 0) / steps / 1e3 for s in order}
        nested = {s for s in order if s.startswith("  ")}  # parts of the stage above them
        out["other"] = total_ns / steps / 1e3 - sum(v for s, v in out.items() if s not in nested)
        return out


def _time_steps(step: Callable[[], None], steps: int, after: Callable[[], None] | None = None) -> np.ndarray:
    """CPU microseconds of each of ``steps`` calls of ``step`` (``after`` runs untimed after each)."""
    clock = time.thread_time_ns
    out = np.empty(steps)
    for k in range(steps):
        t0 = clock()
        step()
        out[k] = (clock() - t0) / 1e3
        if after is not None:
            after()
    return out


ONE_AGENT_STAGES = ["actions check", "agent provider", "map, route, events", "observation", "reward"]


def one_agent(steps: int = 300, warmup: int = 20, stages: bool = False, repeats: int = 3) -> dict:
    """CPU microseconds per env step of one agent (median and mean over ``repeats`` episodes of
    ``steps`` timed steps); with ``stages``, the split by stage."""
    import smarts.env.driving as driving_module
    from smarts.diagnostic.scenarios import CRUISE_SPEED, perf_scenario
    from smarts.env import DrivingParallelEnv

    env = DrivingParallelEnv(perf_scenario(1, steps + warmup))
    sim = env.sim
    timer = StageTimer()
    if stages:
        timer.wrap(sim, "check_actions", "actions check")
        for p in sim.batch_providers:
            timer.wrap(p, "step", "agent provider")
        for name in SETTLE_METHODS:
            timer.wrap(sim, name, "map, route, events")
        timer.wrap(env.driving.sensors, "build", "observation")
        timer.wrap(driving_module, "default_rewards", "reward")
    actions = {a: np.array([CRUISE_SPEED * sim.dt, 0.0, 0.0], dtype=np.float32) for a in env.possible_agents}
    times = []
    for _ in range(repeats):
        env.reset(seed=0)
        for _ in range(warmup):
            env.step(actions)
        timer.ns.clear()
        times.append(_time_steps(lambda: env.step(actions), steps))
        if len(env.agents) != 1:
            raise RuntimeError("the one-agent case lost its agent during timing")
    env.close()
    last = times[-1]
    row = _summary(np.concatenate(times))
    if stages:
        row["stages_us"] = timer.per_step_us(steps, int(last.sum() * 1e3), ONE_AGENT_STAGES)
    return row


SUMO_STAGES = ["agent provider", "sumo provider", "  sumo mirror", "  sumo simulationStep", "  sumo read",
               "map, route, events"]  # fmt: skip


def sumo(n_vehicles: int = 50, steps: int = 300, stages: bool = False, seed: int = 42) -> dict:
    """CPU microseconds per simulation step with ``n_vehicles`` SUMO vehicles on the road (the set-up
    of ``smarts.diagnostic.sumo_step``); with ``stages``, the split by stage."""
    from smarts.core.vehicle_table import Role
    from smarts.diagnostic.sumo_step import benchmark_spec, benchmark_traffic
    from smarts.env.assembly import build_simulation
    from smarts.traffic import sumo_provider
    from smarts.traffic.sumo_provider import SumoTrafficProvider

    spec = benchmark_spec(n_vehicles, seed)
    sim = build_simulation(replace(spec, traffic=benchmark_traffic(n_vehicles)))
    (provider,) = [p for p in sim.providers if isinstance(p, SumoTrafficProvider)]
    timer = StageTimer()
    try:
        sim.reset()
        if stages:
            for p in sim.batch_providers:
                timer.wrap(p, "step", "agent provider")
            timer.wrap(provider, "step", "sumo provider")
            timer.wrap(provider, "_mirror", "  sumo mirror")
            timer.wrap(sumo_provider._C, "simulation_step", "  sumo simulationStep")
            timer.wrap(provider, "_read", "  sumo read")
            for name in SETTLE_METHODS:
                timer.wrap(sim, name, "map, route, events")
        actions = {a: np.zeros(3) for a in sim.agent_ids}
        table = sim.table

        def traffic() -> int:
            return int(np.count_nonzero(table.alive & (table.role == int(Role.TRAFFIC))))

        best, stalled, flows_end = 0, 0, max(n_vehicles / 5.0, 0.1) + 2.0
        while traffic() < n_vehicles and not (sim.time > flows_end and stalled > 20):
            stalled = stalled + 1 if traffic() <= best else 0
            best = max(best, traffic())
            sim.step(actions)
        timer.ns.clear()
        counts: list[int] = []
        times = _time_steps(lambda: sim.step(actions), steps, lambda: counts.append(traffic()))
    finally:
        sim.close()
    row = _summary(times)
    row["vehicles"] = float(np.mean(counts))
    if stages:
        row["stages_us"] = timer.per_step_us(steps, int(times.sum() * 1e3), SUMO_STAGES)
    return row


def _summary(us: np.ndarray) -> dict:
    return {"cpu_us_median": float(np.median(us)), "cpu_us_mean": float(np.mean(us)), "steps": int(us.size)}


_CHILD = """
import json, sys
from smarts.diagnostic import cpu_step
case, steps, warmup = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
row = cpu_step.one_agent(steps, warmup) if case == "1" else cpu_step.sumo(int(case[4:]), steps)
print(json.dumps(row))
"""


def run_in_tree(tree: str | None, case: str, steps: int, warmup: int) -> dict:
    """One CPU case (``1`` or ``sumoN``) in a fresh interpreter importing ``smarts`` from the source
    tree ``tree`` (None: this one), so two trees are timed by the same code in turn."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ)
    root = tree or str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, case, str(steps), str(warmup)], env=env, cwd=root,
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def compare(baseline: str, cases: list[str], steps: int, warmup: int, rounds: int = 3) -> list[dict]:
    """Each case in ``baseline`` (another source tree) and in this tree, alternating for ``rounds``
    rounds (so load on a shared machine hits both alike); per tree the median of the rounds'
    medians, and this tree's over the baseline's."""
    rows = []
    for case in cases:
        times: dict[str, list[float]] = {"baseline": [], "this": []}
        for _ in range(rounds):
            for name, tree in (("baseline", baseline), ("this", None)):
                times[name].append(run_in_tree(tree, case, steps, warmup)["cpu_us_median"])
        base, this = float(np.median(times["baseline"])), float(np.median(times["this"]))
        rows.append({"case": case, "baseline_us": base, "this_us": this, "ratio": this / base, "rounds": times})
    return rows
