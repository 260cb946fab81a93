"""``python -m smarts.diagnostic``: time simulator steps at full load and write a table and JSON.

Cases: 1/10/20/50 RelativeTargetPose agents on the 455 m six-lane highway, every agent building the
full basic observation each step. Agents start spread over the six lanes and cruise straight, so all
of them stay live for the measured steps (full load). Three timings per step are reported:
``sim`` (actions, dynamics, map projection, events, route progress), ``obs`` (batched observation) and
``env`` (a whole PettingZoo ``step`` including both, rewards and the per-agent dicts).

The sensor case (``--sensors``) puts 10 agents with every sensor on (occlusion, 64x64 rasters of all
layers plus RGB, 64-ray lidar, extended neighbours) and V2V messaging (``SENSOR_COMMS``: every agent
sends 8 floats a step, half the traffic broadcasts its state) among 50 built-in traffic vehicles on
the same highway, and splits the observation time into its sensors and the V2V exchange.

The CPU rows (``--cpu``, default ``1,sumo50``) time the two cases where fixed costs dominate in
thread CPU time (``smarts.diagnostic.cpu_step``): the one-agent env step and the simulation step
with 50 SUMO vehicles; ``--stages`` splits each by stage.

The replay cases (``--replay``) replay 1/10/20/50 recorded NGSIM vehicles on the same highway, and 50
with an agent taking one of them over (``smarts.diagnostic.replay_step``).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from smarts.diagnostic.scenarios import (  # noqa: F401  (names the diagnostic reports)
    CRUISE_SPEED,
    END_MARGIN,
    LANES,
    PERF_MAP,
    ROAD_LENGTH,
    SPACING,
    TRAFFIC_SPACING,
    perf_scenario,
    sensor_scenario,
)


def time_case(n_agents: int, steps: int, warmup: int, vehicles: int | None = None) -> dict:
    """Whole-step, simulation and observation times; with ``vehicles``, the sensor case."""
    from smarts.env import DrivingParallelEnv

    if vehicles is None:
        env = DrivingParallelEnv(perf_scenario(n_agents, steps + warmup))
    else:
        env = DrivingParallelEnv(sensor_scenario(n_agents, vehicles, steps + warmup))
    sim, builder = env.sim, env.builder
    parts: dict[str, list[float]] = {"shadows": [], "rasters": [], "lidar": []}
    if env.comms is not None:
        parts["v2v"] = []
    step_dx = np.array([CRUISE_SPEED * sim.dt, 0.0, 0.0], dtype=np.float32)
    driving = {a: step_dx for a in env.possible_agents}
    actions = driving  # what the env takes: with comms, the driving part then the message part
    if env.comms is not None:
        message = np.linspace(-1.0, 1.0, len(env.comms.message_components), dtype=np.float32)
        actions = {a: np.concatenate([step_dx, message]) for a in env.possible_agents}

    def run(mode: str) -> np.ndarray:
        env.reset(seed=0)
        out = np.empty(steps)
        for k in range(warmup + steps):
            t0 = time.perf_counter()
            if mode == "env":
                env.step(actions)
            elif mode == "sim":
                sim.step(driving)
            else:
                sim.step(driving)
                t0 = time.perf_counter()
                builder.build(sim, sim.active_agents)
            if k >= warmup:
                out[k - warmup] = (time.perf_counter() - t0) * 1e3
                if mode == "obs" and vehicles is not None:
                    _time_sensors(builder, sim, parts)
                    if env.comms is not None:
                        _time_v2v(env, actions, parts)
            elif mode == "obs" and env.comms is not None:
                _time_v2v(env, actions, parts, record=False)  # keeps the message queues full
        live = int(sim.agent_active.sum())
        if live != n_agents:
            raise RuntimeError(f"{n_agents}-agent case lost agents during timing ({live} live at the end)")
        return out

    timings = {mode: run(mode) for mode in ("sim", "obs", "env")}
    env.close()
    row = {"agents": n_agents, "steps": steps}
    if vehicles is not None:
        row["vehicles"] = vehicles
        row["live_rows"] = int(len(sim.alive))  # vehicles and agents at the end
        for name, ms in parts.items():
            row[f"{name}_ms_mean"] = float(np.mean(ms))
    for mode, ms in timings.items():
        row[f"{mode}_ms_mean"] = float(ms.mean())
        row[f"{mode}_ms_median"] = float(np.median(ms))
    row["env_steps_per_s"] = 1e3 / row["env_ms_mean"]
    row["agent_steps_per_s"] = n_agents * row["env_steps_per_s"]
    return row


def _time_sensors(builder, sim, parts: dict[str, list[float]]) -> None:
    """Each sensor of the all-sensors build on its own (the rest of ``obs`` is the basic part)."""
    agents = sim.active_agents
    rows = sim.agent_row[agents]
    t0 = time.perf_counter()
    shadows = builder.shadows.scan(sim, agents, rows)
    t1 = time.perf_counter()
    builder.rasters.observe(sim, agents, rows, shadows)
    t2 = time.perf_counter()
    builder.lidar.observe(sim, agents, rows)
    t3 = time.perf_counter()
    parts["shadows"].append((t1 - t0) * 1e3)
    parts["rasters"].append((t2 - t1) * 1e3)
    parts["lidar"].append((t3 - t2) * 1e3)


def _time_v2v(env, actions: dict, parts: dict[str, list[float]], record: bool = True) -> None:
    """The env's V2V work in one step: split the message actions, send, broadcast connected
    traffic, deliver and write the received-messages observation."""
    from smarts.comms import received_to_observation

    sim, comms = env.sim, env.comms
    agents = sim.active_agents
    ids = [sim.agent_ids[i] for i in agents]
    t0 = time.perf_counter()
    _, payloads, channels = comms.split(actions, ids, agents)
    received_to_observation(comms.exchange(agents, payloads, channels)[1])
    if record:
        parts["v2v"].append((time.perf_counter() - t0) * 1e3)


def _sumo_case(n: int, steps: int) -> dict:
    from smarts.diagnostic.sumo_step import sumo_step_benchmark

    r = sumo_step_benchmark(n, steps)
    return {
        "engine": "sumo",
        "vehicles": n,
        "vehicles_on_road": r["vehicles"],
        "step_ms": r["step_ms"],
        "provider_ms": r["sumo_ms"],
    }


def _builtin_case(n: int, steps: int) -> dict:
    from smarts.diagnostic.builtin_step import builtin_step_benchmark

    r = builtin_step_benchmark(n, steps)
    return {
        "engine": "builtin",
        "vehicles": n,
        "vehicles_on_road": r["vehicles_mean"],
        "step_ms": r["sim_step_ms_median"],
        "provider_ms": r["provider_ms_median"],
    }


TRAFFIC_BENCHMARKS = {"sumo": _sumo_case, "builtin": _builtin_case}


def _replay_rows(cases: list[tuple[int, bool]], steps: int, warmup: int, console) -> list[dict]:
    """Time dataset replay (``smarts.diagnostic.replay_step``) and print its table."""
    from rich.progress import track
    from rich.table import Table

    from smarts.diagnostic.replay_step import replay_step_benchmark

    rows = [replay_step_benchmark(n, steps, warmup, take_over) for n, take_over in
            track(cases, description="timing replay", console=console)]  # fmt: skip
    table = Table(title=f"NGSIM replay, {steps} timed steps per case (ms per step; 0: no replay, the reference)")
    for col in ("replayed", "agent", "env median [95% CI]", "env mean", "env p90", "sim median", "replay median"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        lo, hi = r["env_step_ms_median_ci95"]
        table.add_row(
            f"{r['replayed_mean']:.0f}", "takes one over" if r["take_over"] else "aside",
            f"{r['env_step_ms_median']:.3f} [{lo:.3f}, {hi:.3f}]", f"{r['env_step_ms_mean']:.3f}",
            f"{r['env_step_ms_p90']:.3f}", f"{r['sim_step_ms_median']:.3f}", f"{r['provider_ms_median']:.3f}",
        )  # fmt: skip
    console.print(table)
    return rows


def _cpu_rows(cases: list[str], steps: int, warmup: int, stages: bool, console) -> list[dict]:
    """Time the CPU cases (``smarts.diagnostic.cpu_step``) and print them, split by stage with ``stages``."""
    from rich.table import Table

    from smarts.diagnostic import cpu_step

    rows = []
    for case in cases:

        def run(split: bool) -> dict:
            return (
                cpu_step.one_agent(steps, warmup, split) if case == "1" else cpu_step.sumo(int(case[4:]), steps, split)
            )

        row = run(False)  # the headline: no timing wrappers
        name = (
            "1 agent, env step"
            if case == "1"
            else f"{case[4:]} SUMO vehicles ({row['vehicles']:.0f} on the road), simulation step"
        )
        row = {"case": name, **row}
        if stages:
            row["stages_us"] = run(True)["stages_us"]
        rows.append(row)
    table = Table(title=f"Thread CPU time per step, {steps} timed steps (microseconds)")
    for col in ("case", "median", "mean"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        table.add_row(r["case"], f"{r['cpu_us_median']:.1f}", f"{r['cpu_us_mean']:.1f}")
    console.print(table)
    for r in (r for r in rows if "stages_us" in r):
        split = Table(title=f"{r['case']}: CPU by stage (us per step; timing wrappers included)", min_width=100)
        split.add_column("stage", no_wrap=True)
        split.add_column("us", justify="right")
        for stage, us in r["stages_us"].items():
            split.add_row(stage, f"{us:.1f}")
        console.print(split)
    return rows


def _compare_rows(baseline: str, cases: list[str], steps: int, warmup: int, console) -> list[dict]:
    """The CPU cases in ``baseline`` and in this tree, alternating (``cpu_step.compare``), as a table."""
    from rich.table import Table

    from smarts.diagnostic import cpu_step

    rows = cpu_step.compare(baseline, cases, steps, warmup)
    table = Table(
        title=f"Thread CPU time per step against {baseline} (us, median of 3 alternating rounds)", min_width=100
    )
    for col in ("case", "baseline", "this tree", "this / baseline"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        name = "1 agent, env step" if r["case"] == "1" else f"{r['case'][4:]} SUMO vehicles, simulation step"
        table.add_row(name, f"{r['baseline_us']:.1f}", f"{r['this_us']:.1f}", f"{r['ratio']:.2f}")
    console.print(table)
    return rows


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m smarts.diagnostic", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--batched",
        action="store_true",
        help="time the batched backend against the per-env path instead (see --batched --help)",
    )
    parser.add_argument("--agents", default="1,10,20,50", help="comma-separated agent counts (default 1,10,20,50)")
    parser.add_argument("--steps", type=int, default=300, help="timed steps per case (default 300)")
    parser.add_argument("--warmup", type=int, default=20, help="untimed steps first (default 20)")
    parser.add_argument("--vehicles", default="1,10,20,50,200", help="traffic vehicle counts (default 1,10,20,50,200)")
    parser.add_argument(
        "--traffic", default="sumo,builtin", help="traffic engines to time: sumo,builtin (default both; 'none' to skip)"
    )
    parser.add_argument(
        "--sensors",
        default="10:50",
        help="all-sensors case as AGENTS:VEHICLES (default 10:50, built-in traffic); 'none' to skip",
    )
    parser.add_argument(
        "--replay",
        default="0,1,10,20,50,50+",
        help="replayed NGSIM vehicle counts; N+ adds an agent taking one over, 0 is the reference without replay "
        "(default 0,1,10,20,50,50+; 'none' to skip)",
    )
    parser.add_argument(
        "--cpu",
        default="1,sumo50",
        help="CPU-time rows: 1 (one agent, env step) and/or sumoN (N SUMO vehicles, simulation step); 'none' to skip",
    )
    parser.add_argument("--stages", action="store_true", help="split the CPU rows by stage")
    parser.add_argument(
        "--baseline",
        default=None,
        metavar="TREE",
        help="also time the CPU rows with the smarts source tree TREE (e.g. a git worktree of an older commit), "
        "alternating with this one in fresh interpreters, and print the ratios",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/diagnostic.json"), help="JSON output file")
    return parser


def _positive_counts(parser: argparse.ArgumentParser, option: str, text: str) -> list[int]:
    """Comma-separated positive integers, or the parser's error naming ``option``."""
    try:
        counts = [int(c) for c in text.split(",") if c.strip()]
    except ValueError:
        parser.error(f"{option}: expected comma-separated integers, got {text!r}")
    if not counts or min(counts) < 1:
        parser.error(f"{option}: expected positive integers, got {text!r}")
    return counts


def _check_agents(parser: argparse.ArgumentParser, args: argparse.Namespace, counts: list[int]) -> None:
    """The agent counts must stay on the highway for the whole run; steps and warm-up must be sane."""
    travel = CRUISE_SPEED * (args.steps + args.warmup) * 0.1
    max_agents = LANES * (int((ROAD_LENGTH - END_MARGIN - 5.0 - travel) // SPACING) + 1)
    if max(counts) > max_agents:
        parser.error(f"--agents: at most {max_agents} agents stay on the 455 m highway for {args.steps} steps")
    if args.steps < 1 or args.warmup < 0:
        parser.error("--steps must be >= 1 and --warmup >= 0")


def _sensor_case(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[int, int] | None:
    """``--sensors AGENTS:VEHICLES`` (None for ``none``), checked to fit on the highway."""
    if args.sensors == "none":
        return None
    try:
        sensor_case = tuple(int(v) for v in args.sensors.split(":"))
    except ValueError:
        sensor_case = ()
    if len(sensor_case) != 2 or min(sensor_case) < 1:
        parser.error(f"--sensors: expected AGENTS:VEHICLES (positive integers) or none, got {args.sensors!r}")
    travel = CRUISE_SPEED * (args.steps + args.warmup) * 0.1
    rows_needed = -(-sensor_case[0] // LANES) + -(-sensor_case[1] // LANES)
    if 5.0 + TRAFFIC_SPACING * rows_needed + travel > ROAD_LENGTH - END_MARGIN:
        parser.error(f"--sensors: {args.sensors} does not fit on the 455 m highway for {args.steps} steps")
    return sensor_case


def _cpu_cases(parser: argparse.ArgumentParser, text: str) -> list[str]:
    cases = [c.strip() for c in text.split(",") if c.strip() and text != "none"]
    if any(c != "1" and not (c.startswith("sumo") and c[4:].isdigit() and int(c[4:]) > 0) for c in cases):
        parser.error(f"--cpu: expected 1 and/or sumoN (N > 0), or none; got {text!r}")
    return cases


def _replay_cases(parser: argparse.ArgumentParser, text: str) -> list[tuple[int, bool]]:
    """``--replay`` as (replayed vehicles, an agent takes one over) pairs."""
    cases = []
    for item in (c.strip() for c in text.split(",") if c.strip() and text != "none"):
        if not item.rstrip("+").isdigit() or item == "0+":
            parser.error(f"--replay: expected counts such as 1,10,50,50+ or none, got {text!r}")
        cases.append((int(item.rstrip("+")), item.endswith("+")))
    return cases


def _step_rows(counts: list[int], steps: int, warmup: int, console) -> list[dict]:
    """Time the full-load agent cases and print their table."""
    from rich.progress import track
    from rich.table import Table

    rows = [time_case(n, steps, warmup) for n in track(counts, description="timing cases", console=console)]
    table = Table(title=f"Step time at full load, {steps} timed steps per case (ms per step)")
    for col in ("agents", "env step mean", "env step median", "sim mean", "obs mean", "env steps/s", "agent-steps/s"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        table.add_row(
            str(r["agents"]),
            f"{r['env_ms_mean']:.3f}",
            f"{r['env_ms_median']:.3f}",
            f"{r['sim_ms_mean']:.3f}",
            f"{r['obs_ms_mean']:.3f}",
            f"{r['env_steps_per_s']:.0f}",
            f"{r['agent_steps_per_s']:.0f}",
        )
    console.print(table)
    return rows


def _sensor_rows(case: tuple[int, int], steps: int, warmup: int, console) -> list[dict]:
    """Time the all-sensors case and print its table, the observation split by sensor."""
    from rich.table import Table

    rows = [time_case(case[0], steps, warmup, vehicles=case[1])]
    table = Table(
        title=f"All sensors (occlusion, 64x64 rasters + RGB, 64-ray lidar) and V2V, {steps} timed steps (ms per step)"
    )
    for col in ("agents", "vehicles", "env step mean", "env step median", "sim mean", "obs mean",
                "shadows", "rasters", "lidar", "v2v"):  # fmt: skip
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        table.add_row(
            str(r["agents"]),
            str(r["vehicles"]),
            f"{r['env_ms_mean']:.3f}",
            f"{r['env_ms_median']:.3f}",
            f"{r['sim_ms_mean']:.3f}",
            f"{r['obs_ms_mean']:.3f}",
            f"{r['shadows_ms_mean']:.3f}",
            f"{r['rasters_ms_mean']:.3f}",
            f"{r['lidar_ms_mean']:.3f}",
            f"{r['v2v_ms_mean']:.3f}",
        )
    console.print(table)
    return rows


def _traffic_rows(engines: list[str], vehicle_counts: list[int], steps: int, console) -> list[dict]:
    """Time every traffic engine at every vehicle count and print their table."""
    from rich.progress import track
    from rich.table import Table

    rows = []
    cases = [(e, n) for e in engines for n in vehicle_counts]
    for engine, n in track(cases, description="timing traffic", console=console):
        rows.append(TRAFFIC_BENCHMARKS[engine](n, steps))
    table = Table(title=f"Traffic at full load, {steps} timed steps per case (ms per step, median)")
    for col in ("engine", "vehicles", "on the road", "whole step", "traffic provider"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        table.add_row(
            r["engine"],
            str(r["vehicles"]),
            f"{r['vehicles_on_road']:.0f}",
            f"{r['step_ms']:.3f}",
            f"{r['provider_ms']:.3f}",
        )
    console.print(table)
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--batched" in argv:  # the batched backend's rows have their own options
        from smarts.diagnostic.batched_step import main as batched_main

        return batched_main([a for a in argv if a != "--batched"])
    parser = _parser()
    args = parser.parse_args(argv)
    counts = _positive_counts(parser, "--agents", args.agents)
    vehicle_counts = _positive_counts(parser, "--vehicles", args.vehicles)
    engines = [e for e in args.traffic.split(",") if e.strip() and e != "none"]
    unknown = [e for e in engines if e not in TRAFFIC_BENCHMARKS]
    if unknown:
        parser.error(f"--traffic: unknown engine(s) {unknown}; expected sumo, builtin or none")
    _check_agents(parser, args, counts)
    sensor_case = _sensor_case(parser, args)
    cpu_cases = _cpu_cases(parser, args.cpu)
    replay_cases = _replay_cases(parser, args.replay)  # checked with the rest, before any timing

    from rich.console import Console

    console = Console(width=max(Console().width, 110))
    cpu_rows = _cpu_rows(cpu_cases, args.steps, args.warmup, args.stages, console) if cpu_cases else []
    compare_rows = _compare_rows(args.baseline, cpu_cases, args.steps, args.warmup, console) if args.baseline else []
    rows = _step_rows(counts, args.steps, args.warmup, console)
    sensor_rows = _sensor_rows(sensor_case, args.steps, args.warmup, console) if sensor_case is not None else []
    replay_rows = _replay_rows(replay_cases, args.steps, args.warmup, console) if replay_cases else []
    traffic_rows = _traffic_rows(engines, vehicle_counts, args.steps, console) if engines else []
    report = {
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {
            "python": sys.version.split()[0],
            "platform": platform.platform(),
            "processor": platform.processor(),
        },
        "map": PERF_MAP,
        "cases": rows,
        "sensor_cases": sensor_rows,
        "traffic_cases": traffic_rows,
        "replay_cases": replay_rows,
        "cpu_cases": cpu_rows,
        "cpu_baseline": {"tree": args.baseline, "cases": compare_rows} if args.baseline else None,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    console.print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
