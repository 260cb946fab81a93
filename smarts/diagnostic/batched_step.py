"""Throughput of the batched backend against the per-env path, measured in one run
(``python -m smarts.diagnostic --batched``).

A row times B single-agent episodes of one case stepped with random actions and the default
observation, auto-reset included: agent-steps per second of the batched backend
(``BatchedDriving``: one call per stage for all B episodes) and of the per-env path (one
``DrivingParallelEnv`` per episode stepped in turn, as a B = 1 user steps them) on the same
episodes, their ratio, and the memory one episode takes in the batched backend (traced
allocations of building and resetting it, divided by B). Rates are means over ``CHUNKS`` timed
chunks with 95% confidence intervals. Cases:

- ``free_direct``: the agent alone on a straight three-lane road, RelativeTargetPose actions;
- ``free_lane``: the same driven by lane-relative commands (the training controller);
- ``lead_lane``: the adaptive suite's a01_straight_free (a lead vehicle of built-in traffic to
  follow, whose traffic provider steps per episode) with lane-relative commands;
- ``mix_lane``: B copies cycling through every scenario of the adaptive suite (the platoon
  task's mix: 11 scenarios on 7 maps, with traffic, signals and up to three agents per copy) with
  lane-relative commands; all copies are one simulation over the stacked maps.

``--sensor-batch B`` (default 64) adds the sensor rows: B copies of the per-env diagnostic's
all-sensors case (10 agents with occlusion, 64x64 rasters of every layer with RGB, 64-ray lidar,
extended neighbours, and V2V messaging among 50 built-in traffic vehicles) against the same batch
with the sensors and V2V off, and their ratio; ``SMARTS_SENSOR_THREADS`` sets the sensors' threads.
``--sensor-breakdown`` adds a row per sensor alone (and the rasters with and without RGB): the
thread CPU per agent-step of each and what it adds to the sensors-off step.

``--ppo-steps N`` adds end-to-end rows: ``python -m train ppo --task platoon`` run as users run
it, one row per PPO setting, each the env-steps/s the run records over its whole length, the
median seconds per batch of its update and of its wait for collection, and its rate against the
first setting. A setting is one position of the comma-separated ``--ppo-envs``, ``--ppo-frames``, ``--ppo-minibatch``, ``--ppo-epochs``,
``--ppo-workers`` and ``--ppo-lr`` lists (a single value holds for every setting), e.g. the
default compares 1 and 2 worker processes (0 steps the copies in the training process).
``--ppo-rounds R`` runs the settings in turn R times (A B A B ...), so a machine whose speed
drifts slows every setting alike, and reports each setting's median.
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import time
import tracemalloc
from pathlib import Path
from typing import NamedTuple

import numpy as np

from smarts.core.spec import replace
from smarts.sensors.interface import AgentInterface

CASES = {
    "free_direct": ("free", "direct"),
    "free_lane": ("free", "lane_relative"),
    "lead_lane": ("lead", "lane_relative"),
    "mix_lane": ("mix", "lane_relative"),
}
DEFAULT_BATCHES = (1, 16, 64, 256, 1024)
CHUNKS = 5
STRAIGHT = 0.9  # RelativeTargetPose dx (m) of the direct case: 9 m/s straight ahead


def case_specs(case: str, batch: int) -> list:
    """The ``batch`` scenario copies of ``case``, their agents on RelativeTargetPose (direct
    actions or lane-relative commands)."""
    from smarts.benchmark.suites import load_suite

    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; expected one of {', '.join(CASES)}")
    scenario, controller = CASES[case]
    if scenario != "mix":
        return [case_spec(case)] * batch
    suite = [_on_relative_target_pose(s.spec, controller) for s in load_suite("adaptive").scenarios]
    return [suite[k % len(suite)] for k in range(batch)]


def _on_relative_target_pose(spec, controller: str):
    """``spec`` with every agent on RelativeTargetPose driven by ``controller``."""
    agents = [replace(a, action_space="relative_target_pose", controller=controller) for a in spec.agents]
    return replace(spec, agents=agents)


def case_spec(case: str):
    """The single-agent scenario of ``case``, its agent on RelativeTargetPose (direct actions or
    lane-relative commands)."""
    from smarts.benchmark.suites import load_suite
    from smarts.scenario import read_scenario

    if case not in CASES or CASES[case][0] == "mix":
        raise ValueError(
            f"unknown single-scenario case {case!r}; expected one of {', '.join(c for c in CASES if CASES[c][0] != 'mix')}"
        )
    scenario, controller = CASES[case]
    if scenario == "lead":
        spec = next(s.spec for s in load_suite("adaptive").scenarios if s.name == "a01_straight_free")
    else:
        spec = read_scenario(
            {
                "name": "batched_free",
                "map": "builtin:straight_3lane",
                "episode_steps": 200,
                "agents": [{"mission": {"start": {"road": "main", "lane": 1, "offset": 10, "speed": 8},
                                        "goal": {"endless": True}}}],
            },
            source="batched_step_benchmark",
        )  # fmt: skip
    return _on_relative_target_pose(spec, controller)


def _actions(case: str, rng: np.random.Generator, n: int) -> np.ndarray:
    if CASES[case][1] == "direct":
        out = np.zeros((n, 3))
        out[:, 0] = STRAIGHT
        out[:, 2] = rng.uniform(-0.02, 0.02, size=n)
        return out
    return rng.uniform(-1.0, 1.0, size=(n, 2))


def _mean_ci(values: list[float]) -> tuple[float, float]:
    """Mean and the half-width of its 95% confidence interval (t distribution)."""
    from scipy import stats

    arr = np.asarray(values, dtype=float)
    if arr.size < 2:
        return float(arr.mean()), float("nan")
    return float(arr.mean()), float(stats.t.ppf(0.975, arr.size - 1) * arr.std(ddof=1) / np.sqrt(arr.size))


def _timed(step, steps: int, warmup: int) -> tuple[float, float]:
    """Agent-steps/s of ``step()`` (which returns the agent-steps it took): ``warmup`` untimed
    calls, then ``steps`` calls in ``CHUNKS`` timed chunks; the mean rate and its 95% CI."""
    for _ in range(warmup):
        step()
    rates = []
    for _ in range(CHUNKS):
        acted, t0 = 0, time.perf_counter()
        for _ in range(max(1, steps // CHUNKS)):
            acted += step()
        rates.append(acted / (time.perf_counter() - t0))
    return _mean_ci(rates)


def batched_rate(case: str, batch: int, steps: int, warmup: int, seed: int = 0) -> dict:
    """Agent-steps/s (mean, 95% CI over chunks) of ``batch`` episodes in the batched backend, and
    the memory per episode."""
    from smarts.env.batched import BatchedDriving

    specs = case_specs(case, batch)
    tracemalloc.start()
    env = BatchedDriving(specs, observation=AgentInterface())
    env.set_seed(seed)
    env.reset()
    memory = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    rng = np.random.default_rng(seed)
    actions = itertools.cycle([_actions(case, rng, env.num_slots) for _ in range(8)])
    mean, ci = _timed(lambda: int(env.step(next(actions)).acted.sum()), steps, warmup)
    env.close()
    return {"agent_steps_per_s": mean, "ci95": ci, "memory_per_episode_kb": memory / batch / 1024.0}


def per_env_rate(case: str, batch: int, steps: int, warmup: int, seed: int = 0) -> dict:
    """Agent-steps/s (mean, 95% CI over chunks) of ``batch`` episodes on the per-env path."""
    from smarts.env.parallel_env import DrivingParallelEnv

    envs = [DrivingParallelEnv(spec, observation=AgentInterface()) for spec in case_specs(case, batch)]
    episode = [0] * batch
    for i, env in enumerate(envs):
        env.reset(seed=seed + i * 100_003)
    rng = np.random.default_rng(seed)

    def step_all() -> int:
        commands = _actions(case, rng, batch)
        acted = 0
        for i, env in enumerate(envs):
            if not env.agents:
                episode[i] += 1
                env.reset(seed=seed + i * 100_003 + episode[i])
            acted += len(env.agents)
            env.step({a: commands[i] for a in env.agents})  # the copy's agents share its command
        return acted

    mean, ci = _timed(step_all, steps, warmup)
    for env in envs:
        env.close()
    return {"agent_steps_per_s": mean, "ci95": ci}


def batched_rows(batches=DEFAULT_BATCHES, cases=tuple(CASES), steps: int = 300, warmup: int = 10,
                 per_env_agent_steps: int = 5000, progress=None) -> list[dict]:  # fmt: skip
    """One row per (case, batch). The per-env path is timed on about ``per_env_agent_steps``
    agent-steps (at least ``CHUNKS`` steps of the whole batch: it is slow at large B), the batched
    backend on ``steps`` steps of the whole batch."""
    rows = []
    for case in cases:
        for batch in batches:
            fast = batched_rate(case, batch, steps, warmup)
            per_steps = max(CHUNKS, per_env_agent_steps // batch)
            slow = per_env_rate(case, batch, per_steps, min(warmup, per_steps))
            row = {
                "case": case,
                "batch": int(batch),
                "agent_steps_per_s": fast["agent_steps_per_s"],
                "agent_steps_per_s_ci95": fast["ci95"],
                "per_env_agent_steps_per_s": slow["agent_steps_per_s"],
                "per_env_agent_steps_per_s_ci95": slow["ci95"],
                "speedup": fast["agent_steps_per_s"] / slow["agent_steps_per_s"],
                "memory_per_episode_kb": fast["memory_per_episode_kb"],
            }
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows


def sensor_rows(batch: int, steps: int, warmup: int, seed: int = 0) -> list[dict]:
    """Agent-steps/s of ``batch`` copies of the all-sensors case with sensors and V2V on, and off."""
    from smarts.sensors.rays import sensor_threads

    parts = sensor_parts()
    rows = []
    for case, part in (("sensors_v2v", parts["all + v2v"]), ("sensors_off", parts["off"])):
        rate = _sensor_rate(*part, batch, steps, warmup, seed)
        rows.append({"case": case, "batch": int(batch), "agents": SENSOR_AGENTS, "vehicles": SENSOR_VEHICLES,
                     "sensor_threads": sensor_threads(), "agent_steps_per_s": rate["agent_steps_per_s"],
                     "agent_steps_per_s_ci95": rate["agent_steps_per_s_ci95"]})  # fmt: skip
    rows[0]["ratio_to_off"] = rows[0]["agent_steps_per_s"] / rows[1]["agent_steps_per_s"]
    return rows


SENSOR_AGENTS, SENSOR_VEHICLES = 10, 50


def sensor_parts() -> dict[str, tuple[dict | None, dict | None]]:
    """The all-sensors case taken apart: (interface, comms) of each sensor alone, of the rasters
    with and without their RGB image, of everything, and of nothing."""
    from smarts.diagnostic.scenarios import SENSOR_COMMS, SENSOR_INTERFACE

    rasters = SENSOR_INTERFACE["rasters"]
    return {
        "off": (None, None),
        "v2v": (None, SENSOR_COMMS),
        "extended neighbours": ({"neighbours": SENSOR_INTERFACE["neighbours"]}, None),
        "occlusion": ({"occlusion": SENSOR_INTERFACE["occlusion"]}, None),
        "lidar": ({"lidar": SENSOR_INTERFACE["lidar"]}, None),
        "rasters": ({"rasters": {**rasters, "rgb": False}}, None),
        "rasters + rgb": ({"rasters": rasters}, None),
        "all + v2v": (SENSOR_INTERFACE, SENSOR_COMMS),
    }


def _sensor_rate(interface: dict | None, comms: dict | None, batch: int, steps: int, warmup: int,
                 seed: int) -> dict[str, float]:  # fmt: skip
    """``batch`` copies of the all-sensors case with ``interface`` and ``comms``, everyone cruising:
    agent-steps/s (mean, 95% CI) and thread CPU per agent-step, after ``warmup`` untimed steps
    (which compile what is not cached yet)."""
    from smarts.diagnostic.scenarios import sensor_scenario
    from smarts.env.batched import BatchedDriving

    spec = sensor_scenario(SENSOR_AGENTS, SENSOR_VEHICLES, steps + warmup + 10, interface, comms)
    env = BatchedDriving([spec] * batch)
    env.set_seed(seed)
    env.reset()
    actions = np.zeros((env.num_slots, env.action_width))
    actions[:, 0] = 0.8  # cruise straight at 8 m/s with the traffic
    for _ in range(warmup):
        env.step(actions)
    cpu, acted = 0.0, 0

    def step() -> int:
        nonlocal cpu, acted
        began = time.thread_time()
        n = int(env.step(actions).acted.sum())
        cpu += time.thread_time() - began
        acted += n
        return n

    mean, ci = _timed(step, steps, 0)
    env.close()
    return {"agent_steps_per_s": mean, "agent_steps_per_s_ci95": ci, "us_per_agent_step": 1e6 * cpu / max(acted, 1)}


def sensor_breakdown_rows(batch: int, steps: int, warmup: int, seed: int = 0) -> list[dict]:
    """Each of ``sensor_parts`` on ``batch`` copies of the all-sensors case: agent-steps/s, thread
    CPU per agent-step (a sensor's cost is its row's less the ``off`` row's: rasters need the
    occlusion buffer for their occlusion layer, so they include it)."""
    rows = [{"case": case, "batch": int(batch), **_sensor_rate(*part, batch, steps, warmup, seed)}
            for case, part in sensor_parts().items()]  # fmt: skip
    for r in rows:
        r["extra_us_per_agent_step"] = r["us_per_agent_step"] - rows[0]["us_per_agent_step"]
    return rows


class PPOSetting(NamedTuple):
    """The options of one end-to-end PPO row (``lr`` None: the task config's)."""

    envs: int
    frames: int
    minibatch: int
    epochs: int
    workers: int
    lr: float | None = None

    def label(self) -> str:
        lr = "" if self.lr is None else f", lr {self.lr:g}"
        return (f"{self.envs} copies, {self.frames} frames, minibatch {self.minibatch}, {self.epochs} epochs, "
                f"{self.workers} workers{lr}")  # fmt: skip


def ppo_rate(setting: PPOSetting, steps: int, out: Path, extra: tuple[str, ...] = ()) -> dict:
    """End-to-end env-steps/s of ``python -m train ppo --task platoon`` on the batched backend with
    ``setting``: run as users run it (a subprocess writing its run to the new folder ``out``), the
    rate read from the metrics of its final checkpoint."""
    import subprocess
    import sys

    import torch

    command = [
        sys.executable, "-m", "train", "ppo", "--task", "platoon", "--backend", "batched",
        "--envs", str(setting.envs), "--workers", str(setting.workers), "--total-steps", str(steps),
        "--frames-per-batch", str(setting.frames), "--minibatch-size", str(setting.minibatch),
        "--epochs", str(setting.epochs), *(("--lr", repr(setting.lr)) if setting.lr is not None else ()),
        "--eval-episodes", "0", "--out-dir", str(out), "--quiet", *extra,
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr[-2000:]}")
    metrics = torch.load(Path(out) / "final.pt", weights_only=True)["metrics"]
    per_batch = _tensorboard_series(Path(out) / "tensorboard", ("perf/update_s", "perf/wait_s"))
    return {
        **setting._asdict(), "total_steps": steps, "options": list(extra),
        "env_steps_per_s": float(metrics["perf/env_steps_per_s"]),
        # Medians over the batches: the last batch's own figures (in final.pt) have no collection
        # running beside its update.
        "update_s": float(np.median(per_batch["perf/update_s"])) if per_batch["perf/update_s"] else float("nan"),
        "wait_s": float(np.median(per_batch["perf/wait_s"])) if per_batch["perf/wait_s"] else float("nan"),
        "episode_return": float(metrics.get("episode/return", float("nan"))),
    }  # fmt: skip


def _tensorboard_series(folder: Path, tags: tuple[str, ...]) -> dict[str, list[float]]:
    """The values of ``tags`` in a run's TensorBoard events, in step order."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    events.Reload()
    found = events.Tags()["scalars"]
    return {tag: [e.value for e in events.Scalars(tag)] if tag in found else [] for tag in tags}


def ppo_rows(settings: list[PPOSetting], steps: int, rounds: int, folder: Path, extra: tuple[str, ...] = (),
             progress=None) -> list[dict]:  # fmt: skip
    """One row per setting: the settings run in turn ``rounds`` times (runs under ``folder``, a new
    folder per run), each row with its runs' rates, their median and its ratio to the first
    setting's median."""
    runs: list[list[dict]] = [[] for _ in settings]
    for r in range(rounds):
        for k, setting in enumerate(settings):
            if progress is not None:
                progress(f"PPO round {r + 1}/{rounds}, setting {k + 1}/{len(settings)}: {setting.label()}")
            runs[k].append(ppo_rate(setting, steps, Path(folder) / f"setting{k}_round{r}", extra))
    rows = []
    for setting, done in zip(settings, runs):
        rates = [run["env_steps_per_s"] for run in done]
        rows.append({
            **done[0], "rounds": rounds, "env_steps_per_s": float(np.median(rates)), "runs_env_steps_per_s": rates,
            "update_s": float(np.median([run["update_s"] for run in done])),
            "wait_s": float(np.median([run["wait_s"] for run in done])),
            "episode_return": [run["episode_return"] for run in done],
        })  # fmt: skip
    for row in rows:
        row["ratio_to_first"] = row["env_steps_per_s"] / rows[0]["env_steps_per_s"]
    return rows


def _ints(text: str, flag: str, parser: argparse.ArgumentParser, least: int = 1) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values or min(values) < least:
        what = "positive integers" if least == 1 else f"integers >= {least}"
        parser.error(f"{flag}: expected comma-separated {what}, got {text!r}")
    return values


def _floats(text: str, flag: str, parser: argparse.ArgumentParser) -> list[float]:
    """Comma-separated positive numbers (empty text: none)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = [-1.0]
    if values and not all(0 < v < float("inf") for v in values):
        parser.error(f"{flag}: expected comma-separated positive numbers, got {text!r}")
    return values


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m smarts.diagnostic --batched",
        description="Batched backend against the per-env path: agent-steps/s, memory per episode, PPO env-steps/s.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--batches", default=",".join(map(str, DEFAULT_BATCHES)), help="episode counts B ('none': no backend rows)"
    )
    parser.add_argument("--cases", default=",".join(CASES), help=f"cases among {', '.join(CASES)}")
    parser.add_argument(
        "--steps", type=int, default=300, help="timed steps of the whole batch per row (batched backend)"
    )
    parser.add_argument(
        "--per-env-agent-steps", type=int, default=5000, help="timed agent-steps per row on the per-env path"
    )
    parser.add_argument("--warmup", type=int, default=10, help="untimed steps first")
    parser.add_argument("--sensor-batch", type=int, default=64, help="copies of the all-sensors rows (0: none)")
    parser.add_argument(
        "--sensor-breakdown",
        action="store_true",
        help="also time each sensor alone at --sensor-batch copies (thread CPU per agent-step against sensors off)",
    )
    parser.add_argument(
        "--ppo-steps", type=int, default=0, help="env steps of each end-to-end PPO run (0: no PPO rows)"
    )
    parser.add_argument("--ppo-envs", default="256", help="scenario copies of the PPO runs (a list: one per setting)")
    parser.add_argument("--ppo-frames", default="16384", help="frames per batch of the PPO runs (a list)")
    parser.add_argument("--ppo-minibatch", default="4096", help="minibatch size of the PPO runs (a list)")
    parser.add_argument("--ppo-epochs", default="4", help="epochs of the PPO runs (a list)")
    parser.add_argument(
        "--ppo-workers", default="1,2", help="worker processes of the PPO runs (a list; 0: the training process)"
    )
    parser.add_argument("--ppo-lr", default="", help="learning rates of the PPO runs (a list; empty: the task's)")
    parser.add_argument(
        "--ppo-rounds", type=int, default=1, help="times every PPO setting runs, in turn with the others"
    )
    parser.add_argument(
        "--ppo-options",
        default="",
        help="more `python -m train ppo` options for every PPO run, e.g. '--device cuda --torch-threads 2'",
    )
    parser.add_argument("--ppo-dir", type=Path, default=Path("runs/diagnostic_ppo"), help="where the PPO runs write")
    parser.add_argument("--out", type=Path, default=Path("reports/diagnostic_batched.json"), help="JSON output file")
    return parser


def _checked(parser: argparse.ArgumentParser, argv: list[str] | None) -> tuple[argparse.Namespace, list, list, list]:
    """The options, with the batch sizes, cases and PPO worker counts they name (or the parser's error)."""
    args = parser.parse_args(argv)
    batches = [] if args.batches.strip() == "none" else _ints(args.batches, "--batches", parser)
    cases = [c for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown or not cases:
        parser.error(f"--cases: unknown case(s) {unknown}; expected some of {', '.join(CASES)}")
    if args.steps < CHUNKS or args.warmup < 0 or args.per_env_agent_steps < 1 or args.ppo_steps < 0:
        parser.error(f"--steps must be >= {CHUNKS}, --warmup >= 0, --per-env-agent-steps >= 1, --ppo-steps >= 0")
    if args.ppo_rounds < 1:
        parser.error(f"--ppo-rounds: expected a positive integer, got {args.ppo_rounds}")
    return args, batches, cases, _ppo_settings(args, parser)


def _ppo_settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> list[PPOSetting]:
    """The PPO settings the ``--ppo-*`` lists name (position k of every list; single values broadcast)."""
    lists = {
        "--ppo-envs": _ints(args.ppo_envs, "--ppo-envs", parser),
        "--ppo-frames": _ints(args.ppo_frames, "--ppo-frames", parser),
        "--ppo-minibatch": _ints(args.ppo_minibatch, "--ppo-minibatch", parser),
        "--ppo-epochs": _ints(args.ppo_epochs, "--ppo-epochs", parser),
        "--ppo-workers": _ints(args.ppo_workers, "--ppo-workers", parser, least=0),
        "--ppo-lr": _floats(args.ppo_lr, "--ppo-lr", parser) or [None],
    }
    count = max(len(v) for v in lists.values())
    uneven = [flag for flag, values in lists.items() if len(values) not in (1, count)]
    if uneven:
        parser.error(f"{', '.join(uneven)}: give one value or {count} (one per PPO setting), as the longest list has")
    settings = [PPOSetting(*(v[k] if len(v) > 1 else v[0] for v in lists.values())) for k in range(count)]
    for s in settings:
        if args.ppo_steps and s.minibatch > s.frames:
            parser.error(f"--ppo-minibatch must be <= --ppo-frames (setting {s.label()})")
    return settings


def _print_batched(rows: list[dict], console) -> None:
    from rich.table import Table

    table = Table(title="Batched backend vs per-env path (agent-steps/s, mean ± 95% CI over 5 chunks)")
    for col in ("case", "B", "batched", "per-env", "speed-up", "memory/episode"):
        table.add_column(col, justify="right", no_wrap=True)
    for r in rows:
        table.add_row(
            r["case"], str(r["batch"]), f"{r['agent_steps_per_s']:,.0f} ± {r['agent_steps_per_s_ci95']:,.0f}",
            f"{r['per_env_agent_steps_per_s']:,.0f} ± {r['per_env_agent_steps_per_s_ci95']:,.0f}",
            f"{r['speedup']:.1f}x", f"{r['memory_per_episode_kb']:.0f} KiB",
        )  # fmt: skip
    console.print(table)


def _sensors(args: argparse.Namespace, console) -> list[dict]:
    """The all-sensors rows at ``--sensor-batch`` copies, printed."""
    from rich.table import Table

    sensors = sensor_rows(args.sensor_batch, max(args.steps // 5, CHUNKS), args.warmup)
    table = Table(title=f"All sensors and V2V, batched ({SENSOR_AGENTS} agents and {SENSOR_VEHICLES} vehicles per "
                        f"episode, B={args.sensor_batch}, {sensors[0]['sensor_threads']} sensor thread(s))")  # fmt: skip
    for col in ("case", "agent-steps/s", "ratio"):
        table.add_column(col, justify="right")
    for r in sensors:
        table.add_row(r["case"], f"{r['agent_steps_per_s']:,.0f} ± {r['agent_steps_per_s_ci95']:,.0f}",
                      f"{r['agent_steps_per_s'] / sensors[1]['agent_steps_per_s']:.2f}x")  # fmt: skip
    console.print(table)
    return sensors


def _breakdown(args: argparse.Namespace, console) -> list[dict]:
    """The per-sensor rows at ``--sensor-batch`` copies, printed."""
    from rich.table import Table

    rows = sensor_breakdown_rows(args.sensor_batch, max(args.steps // 5, CHUNKS), args.warmup)
    table = Table(title=f"Each sensor alone, batched ({SENSOR_AGENTS} agents and {SENSOR_VEHICLES} vehicles per "
                        f"episode, B={args.sensor_batch}; thread CPU per agent-step)")  # fmt: skip
    for col in ("case", "agent-steps/s", "us per agent-step", "over sensors off"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(r["case"], f"{r['agent_steps_per_s']:,.0f} ± {r['agent_steps_per_s_ci95']:,.0f}",
                      f"{r['us_per_agent_step']:.1f}", f"{r['extra_us_per_agent_step']:+.1f}")  # fmt: skip
    console.print(table)
    return rows


def _ppo(args: argparse.Namespace, settings: list[PPOSetting], console) -> list[dict]:
    """The end-to-end PPO rows of ``settings``, printed against the first."""
    from datetime import datetime

    from rich.table import Table

    folder = args.ppo_dir / datetime.now().strftime("%Y%m%d-%H%M%S-%f")  # a new folder: runs never clash
    rows = ppo_rows(settings, args.ppo_steps, args.ppo_rounds, folder, tuple(args.ppo_options.split()), console.log)
    table = Table(title=f"PPO platoon end to end ({args.ppo_steps} steps per run, median of {args.ppo_rounds} "
                        f"alternated run(s){', ' + args.ppo_options if args.ppo_options else ''})")  # fmt: skip
    for col in ("setting", "env-steps/s end to end", "runs", "ratio", "update s/batch", "wait s/batch"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(PPOSetting(*(r[f] for f in PPOSetting._fields)).label(), f"{r['env_steps_per_s']:,.0f}",
                      ", ".join(f"{v:,.0f}" for v in r["runs_env_steps_per_s"]), f"{r['ratio_to_first']:.2f}x",
                      f"{r['update_s']:.2f}", f"{r['wait_s']:.2f}")  # fmt: skip
    console.print(table)
    return rows


def main(argv: list[str] | None = None) -> int:
    args, batches, cases, settings = _checked(_parser(), argv)

    from rich.console import Console

    console = Console(width=max(Console().width, 120))
    rows = batched_rows(batches, cases, args.steps, args.warmup, args.per_env_agent_steps,
                        progress=lambda r: console.log(f"{r['case']} B={r['batch']}: {r['agent_steps_per_s']:.0f} agent-steps/s"))  # fmt: skip
    if rows:
        _print_batched(rows, console)
    sensors = _sensors(args, console) if args.sensor_batch else []
    breakdown = _breakdown(args, console) if args.sensor_batch and args.sensor_breakdown else []
    ppo = _ppo(args, settings, console) if args.ppo_steps else []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    report = {
        "machine": {
            "python": platform.python_version(),
            "processor": platform.processor(),
            "system": platform.platform(),
        },
        "rows": rows,
        "sensors": sensors,
        "sensor_breakdown": breakdown,
        "ppo": ppo,
    }
    args.out.write_text(json.dumps(report, indent=2))
    console.print(f"written: {args.out}")
    return 0
