"""Trajectory logger: every road user's track at 10 Hz, read from the vehicle table, as data sets.

``python -m train trajectories`` runs the benchmark suites' scenarios (all maps, densities and
both traffic engines they use) with the mission vehicles driven by keep-lane, records after every
step the state of every vehicle in the table (id-stable columns: x, y, heading, speed, length,
width, present) and writes one ``<scenario>.npz`` per scenario, holding ``seed<k>`` arrays
[steps, vehicles, 7]. The planners' learned parts train on these files (``train.aid_predictor``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

COLUMNS = ("x", "y", "heading", "speed", "length", "width", "present")


class TableRecorder:
    """Appends one frame of the vehicle table per call; vehicle ids map to fixed columns."""

    def __init__(self) -> None:
        self.frames: list[dict[int, np.ndarray]] = []
        self.columns: dict[str, int] = {}

    def record(self, sim) -> None:
        table = sim.table
        rows = table.alive_rows
        frame = {}
        for row in rows.tolist():
            vid = table.ids[row]
            col = self.columns.setdefault(vid, len(self.columns))
            frame[col] = row
        data = table.data[:, rows] if rows.size else np.zeros((len(table.FLOAT_COLUMNS), 0))
        names = table.FLOAT_COLUMNS
        pick = [names.index(n) for n in COLUMNS[:-1]]
        values = data[pick].T  # [rows, 6]
        self.frames.append({col: values[i] for i, col in enumerate(frame)})

    def array(self) -> np.ndarray:
        """[steps, vehicles, 7] float32; absent vehicles are zero with present = 0."""
        out = np.zeros((len(self.frames), len(self.columns), len(COLUMNS)), dtype=np.float32)
        for t, frame in enumerate(self.frames):
            for col, values in frame.items():
                out[t, col, :6] = values
                out[t, col, 6] = 1.0
        return out


def log_episode(spec, seed: int, steps: int) -> np.ndarray:
    """One episode of a scenario spec with keep-lane mission vehicles -> [steps, vehicles, 7]."""
    from agents.keep_lane import KeepLanePolicy
    from smarts.env import DrivingParallelEnv

    env = DrivingParallelEnv(spec)
    policy = KeepLanePolicy()
    recorder = TableRecorder()
    try:
        obs, _ = env.reset(seed=seed)
        recorder.record(env.sim)
        env.add_step_listener(recorder.record)
        for _ in range(steps):
            if not env.agents and env.sim.table.alive_rows.size == 0:
                break
            actions = {}
            if env.agents:
                batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
                actions = dict(zip(env.agents, policy.act(batch)))
            obs, *_ = env.step(actions)
    finally:
        env.close()
    return recorder.array()


def log_suites(out: Path, suites: list[str], seeds: int, first_seed: int = 0, steps: int | None = None,
               progress: bool = True) -> list[Path]:  # fmt: skip
    """Log ``seeds`` episodes of every scenario of the named suites into ``out``; returns the files."""

    from smarts.benchmark.suites import load_suite
    from train.run import Bar

    out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for name in suites:
        suite = load_suite(name)
        for entry in suite.scenarios:
            jobs.append(entry)
    files = []
    bar = Bar(total=len(jobs) * seeds, desc="logging trajectories", disable=not progress)
    for entry in jobs:
        # traffic keeps driving after the mission vehicles finish: log the whole time limit
        spec = entry.spec
        n = steps or int(round(entry.time_limit / spec.step_length))
        arrays = {}
        for k in range(seeds):
            arrays[f"seed{first_seed + k}"] = log_episode(spec, first_seed + k, n)
            bar.update(1)
        path = out / f"{entry.name}.npz"
        np.savez_compressed(path, **arrays)
        files.append(path)
    bar.close()
    return files


def add_options(p: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """The options of ``python -m train trajectories`` (its command is listed in ``train.__main__``)."""
    p.add_argument("--out", type=Path, default=Path("runs/data/trajectories"), help="output folder")
    p.add_argument("--suite", action="append", default=None, help="suites to log (default: collaborative and adaptive)")
    p.add_argument("--seeds", type=int, default=4, help="episodes per scenario")
    p.add_argument("--first-seed", type=int, default=0, help="seed of the first episode")
    p.add_argument("--steps", type=int, default=None, help="steps per episode (default: the scenario's time limit)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_run)


def _run(args: argparse.Namespace) -> int:
    files = log_suites(args.out, args.suite or ["collaborative", "adaptive"], args.seeds, args.first_seed,
                       args.steps, not args.quiet)  # fmt: skip
    total = sum(int(np.load(f)[k][..., 6].sum()) for f in files for k in np.load(f).files)
    print(f"{len(files)} files, {total} vehicle-steps -> {args.out}")
    return 0
