"""Mutation run: does the test suite notice plausible bugs?

    python -m tests.mutation                 # every mutation, each against its own test folders
    python -m tests.mutation --list          # what each mutation does
    python -m tests.mutation --only reward-no-collision --only sb3-gamma-ignored
    python -m tests.mutation --full          # each mutation against the whole suite (slow)

Each mutation is one small edit of the simulator, metrics, recorder, rewards or trainers, of the
kind a real change could make by mistake (a column logged as zero, a penalty dropped, a setting
not passed on, a loop that skips a row). The checkout is copied once to a temporary folder (numba's
on-disk cache with it, so kernels are not recompiled); each mutation is applied to the copy, the
tests run there with ``pytest -x``, and the file is restored. A mutation is *caught* when pytest
fails, *missed* when it passes, and *stale* when its original text is no longer in the file (the
code moved on: update the list). The checkout itself is never edited.

Exit status: 0 when every mutation is caught, 1 otherwise.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str
    original: str
    mutant: str
    tests: tuple[str, ...]
    why: str


BENCH = ("tests/benchmark",)
ENV = ("tests/env", "tests/core")
TRAIN = ("tests/test_train_run.py", "tests/test_train_ppo.py", "tests/test_learning.py")

MUTATIONS: tuple[Mutation, ...] = (
    # The recorder: the log columns the metrics score.
    Mutation("recorder-jerk-zero", "smarts/benchmark/recorder.py",
             "t.jerk[rows], self._lat_jerk(agents, rows)", "0.0 * t.jerk[rows], self._lat_jerk(agents, rows)",
             BENCH, "longitudinal jerk logged as 0"),
    Mutation("recorder-lateral-jerk-zero", "smarts/benchmark/recorder.py",
             "(lat - self._prev_lat[agents]) / self.sim.dt)", "(lat - self._prev_lat[agents]) / self.sim.dt * 0.0)",
             BENCH, "lateral jerk logged as 0"),
    Mutation("recorder-partial-off-road-false", "smarts/benchmark/recorder.py",
             # the batched recorder's row (the benchmark's default; a test holds it equal to the per-episode one)
             "lat_jerk,\n                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,\n"
             "                ev[:, Event.WRONG_WAY], ev[:, Event.PARTIAL_OFF_ROAD],",
             "lat_jerk,\n                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,\n"
             "                ev[:, Event.WRONG_WAY], 0 * ev[:, Event.PARTIAL_OFF_ROAD],",
             BENCH, "partial off-road flag always false"),
    Mutation("recorder-offset-unsigned", "smarts/benchmark/recorder.py",
             "lat_jerk,\n                t.t[rows], rm.lane_width[lane]", "lat_jerk,\n                np.abs(t.t[rows]), rm.lane_width[lane]",
             BENCH, "lane offset logged without its sign"),
    Mutation("recorder-follow-gap-halved", "smarts/benchmark/recorder.py",
             "gap = np.where(in_lane, gap_s, np.nan)", "gap = np.where(in_lane, 0.5 * gap_s, np.nan)",
             BENCH, "time gap to the follow margin halved"),
    # Metrics.
    Mutation("sbench-rc-weight-on-humanness", "smarts/benchmark/metrics/scores.py",
             '(w.rc, metrics["RC"]),', '(w.rc, metrics["Humanness"]),',
             BENCH, "S_bench weighs Humanness where RC belongs"),
    # Rewards.
    Mutation("reward-no-collision", "smarts/env/reward.py",
             "        r -= weights[1, w] * events[a, _COLLISION]\n", "",
             ENV, "default reward loses its collision penalty"),
    Mutation("reward-no-off-road", "smarts/env/reward.py",
             "        r -= weights[2, w] * events[a, _OFF_ROAD]\n", "",
             ENV, "default reward loses its off-road penalty"),
    Mutation("reward-no-goal", "smarts/env/reward.py",
             "        r += weights[3, w] * events[a, _GOAL]\n", "",
             ENV, "default reward loses its goal bonus"),
    Mutation("task-reward-no-collision", "smarts/env/task_rewards.py",
             "            - w.collision * ev[:, Event.COLLISION]\n", "",
             ENV, "task reward loses its collision penalty"),
    Mutation("task-reward-no-wrong-way", "smarts/env/task_rewards.py",
             "            - w.wrong_way * ev[:, Event.WRONG_WAY]\n", "",
             ENV, "task reward loses its wrong-way penalty"),
    # Events and dynamics.
    Mutation("collision-skips-last-row", "smarts/core/events.py",
             "    for j in alive:\n        if j == r:", "    for j in alive[:-1]:\n        if j == r:",
             ENV, "agents are never tested against the last live row"),
    Mutation("collision-kernel-skips-neighbour-row", "smarts/core/events.py",
             "        for j in range(i + 1, n):", "        for j in range(i + 2, n):",
             ENV, "the all-pairs kernel skips adjacent rows"),
    Mutation("partial-off-road-two-corners", "smarts/core/events.py",
             "    for k in range(4):\n        if not on_road_at", "    for k in range(2):\n        if not on_road_at",
             ENV, "partial off-road looks at the front corners only"),
    Mutation("wrong-way-never", "smarts/core/events.py",
             "math.cos(h - data[_LANE_HEADING, r]) < 0.0", "math.cos(h - data[_LANE_HEADING, r]) < -2.0",
             ENV, "wrong way never flagged"),
    Mutation("pose-no-accel-limit", "smarts/dynamics/pose_control.py",
             "    d = min(max(d, d_min), d_max)\n", "",
             ("tests/dynamics",), "pose actions ignore the acceleration limits"),
    Mutation("lane-change-right-disabled", "smarts/dynamics/lane_relative.py",
             "side = 1 if cmd[i, 1] > threshold else (-1 if cmd[i, 1] < -threshold else 0)",
             "side = 1 if cmd[i, 1] > threshold else 0",
             ("tests/dynamics", "tests/env"), "lane-relative commands never change to the right"),
    Mutation("lane-projection-no-fallback", "smarts/dynamics/lane_relative.py",
             "    if (k == lo and lo > a) or (k == hi and hi < last):\n", "    if False:\n",
             ("tests/dynamics",), "the lane search near a hint never falls back to the whole lane"),
    Mutation("batched-rows-on-the-first-map", "smarts/core/simulation.py",
             "self.row_map = np.repeat(self.episode_map, cap)", "self.row_map = np.repeat(self.episode_map * 0, cap)",
             ("tests/batched/test_batched_backend.py",), "a batch over several maps projects every row onto the first map"),
    Mutation("stacked-raster-of-the-first-map", "smarts/core/events.py",
             "    m = et.episode_map[b]\n", "    m = 0\n",
             ("tests/batched/test_batched_backend.py",), "a batch over several maps tests on-road against the first map's raster"),
    Mutation("batched-traffic-first-tables", "smarts/traffic/builtin/stage.py",
             "        t = set_of[k]\n", "        t = 0\n", ("tests/batched/test_batched_backend.py",),
             "the batched traffic call gives every provider the first set's route and junction tables"),
    Mutation("record-progress-fields-swapped", "smarts/core/sim_records.py",
             "route_progress=sim.route_progress, progress_delta=sim.route_progress_delta,",
             "route_progress=sim.route_progress_delta, progress_delta=sim.route_progress,",
             ("tests/core",), "two same-typed arrays swapped where a kernel record is built"),
    Mutation("end-of-map-is-off-road", "smarts/core/events.py",
             "        finished = at_step_limit or left_map\n", "        finished = at_step_limit\n",
             ("tests/core/test_end_of_map.py",), "driving to the end of the map does not end the episode"),
    Mutation("episode-scope-all-rows", "smarts/core/simulation.py",
             "        lo = np.searchsorted(alive, episode * cap)\n", "        lo = np.zeros(len(agents), np.int64)\n",
             ("tests/golden/test_golden.py",), "an agent's sensors see other episodes' road users"),
    Mutation("lidar-noise-stream-of-the-batch", "smarts/sensors/lidar.py",
             "self.episode_streams.get(episode, self._stream)", "self._stream",
             ("tests/golden/test_golden.py",), "lidar noise depends on the other episodes' interface groups"),
    Mutation("torch-pose-heading-unwrapped", "smarts/dynamics/pose_control_torch.py",
             "_wrap(h + dh),", "h + dh,", ("tests/dynamics/test_pose_control_torch.py",),
             "the torch pose stage leaves headings past +-pi unwrapped"),
    Mutation("lead-row-cache-unchecked", "smarts/core/following.py",
             "hit = (cached >= 0) & table.alive[cached] & (table.serial[cached] == serials[agents])",
             "hit = (cached >= 0) & table.alive[cached]", ("tests/core",),
             "a cached lead row is trusted after another vehicle took the row"),
    Mutation("episode-timeout-ignored", "smarts/benchmark/pool.py",
             "and time.monotonic() - w.since >= self.timeout:", "and False:",
             ("tests/benchmark/test_runner_failures.py",), "a hung episode holds its worker past the timeout"),
    # Trainers and the run contract.
    Mutation("torchrl-gamma-ignored", "train/ppo.py",
             "cfg.gamma, cfg.gae_lambda, value.T", "0.99, cfg.gae_lambda, value.T", TRAIN, "torchrl's GAE ignores the configured discount"),
    Mutation("torchrl-lambda-ignored", "train/ppo.py",
             "cfg.gamma, cfg.gae_lambda, value.T", "cfg.gamma, 0.95, value.T", TRAIN, "torchrl's GAE ignores the configured lambda"),
    Mutation("sb3-gamma-ignored", "train/sb3_ppo.py",
             "        gamma=cfg.gamma,\n", "        gamma=0.99,\n", TRAIN, "SB3's PPO ignores the configured discount"),
    Mutation("sb3-init-std-ignored", "train/sb3_ppo.py",
             "        model.policy.log_std.copy_(", "        model.policy.log_std.clone().copy_(",
             TRAIN, "SB3 starts from its own action std"),
    Mutation("ppo-next-value-at-episode-ends", "train/ppo.py",
             "            if not last:  # the last step's next observations are taken below, for every slot",
             "            if False:",
             TRAIN, "the value after an episode's last step is taken from the next episode's first"),
    Mutation("periodic-eval-never-runs", "train/run.py",
             "if periodic and cfg.eval_episodes and step < cfg.total_steps:", "if False:",
             TRAIN, "evaluations every eval_every steps never run"),
    Mutation("eval-scalars-dropped", "train/run.py",
             '            writer.add_scalar(f"eval/{name}", value, step)', "            pass",
             TRAIN, "evaluation metrics never reach TensorBoard"),
    Mutation("best-checkpoint-not-saved", "train/run.py",
             '                save(self.out / "best.pt")\n                self.writer.add_scalar(',
             "                self.writer.add_scalar(",
             TRAIN, "best.pt is not written at periodic evaluations"),
    Mutation("best-is-the-latest", "train/run.py",
             'if scores.get("S_bench", -np.inf) > self.best_score:  # selection on held-out seeds',
             "if True:", TRAIN, "best.pt is the latest evaluated checkpoint, not the best"),
)  # fmt: skip


def _copy_checkout(dest: Path) -> None:
    """The project's files (with numba's cache in __pycache__, timestamps kept) into ``dest``."""
    skip = shutil.ignore_patterns(".git", ".venv", "venv", "runs", ".pytest_cache", "*.egg-info", "build", "dist")
    for name in ("pyproject.toml", "README.md", "smarts", "agents", "zoo", "train", "configs", "tests", "docs"):
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=skip, symlinks=True)
        elif src.is_file():
            shutil.copy2(src, dest / name)


def _run(mutation: Mutation, copy: Path, full: bool, timeout: float) -> tuple[str, float, str]:
    """(outcome, seconds, the first failing test) of one mutation."""
    target = copy / mutation.path
    text = target.read_text()
    if text.count(mutation.original) != 1:
        return "stale", 0.0, ""
    stat = target.stat()
    target.write_text(text.replace(mutation.original, mutation.mutant))
    env = {**os.environ, "PYTHONPATH": str(copy), "PYTHONDONTWRITEBYTECODE": "1"}
    tests = ["tests"] if full else list(mutation.tests)
    start = time.perf_counter()
    failed = ""
    try:
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-x", "-q", "-rf", "-p", "no:cacheprovider", *tests],
            cwd=copy, env=env, capture_output=True, text=True, timeout=timeout,
        )  # fmt: skip
        outcome = (
            "missed" if done.returncode == 0 else "caught" if done.returncode == 1 else f"error({done.returncode})"
        )
        failed = next((line.split(" - ")[0].removeprefix("FAILED ") for line in done.stdout.splitlines()
                       if line.startswith("FAILED ")), "")  # fmt: skip
    except subprocess.TimeoutExpired:
        outcome = "timeout"
    finally:
        target.write_text(text)
        os.utime(target, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # numba's cache stays valid
    return outcome, time.perf_counter() - start, failed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.mutation", description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", metavar="NAME", help="run only these mutations (repeatable)")
    parser.add_argument("--full", action="store_true", help="run the whole suite for each mutation (slow)")
    parser.add_argument("--list", action="store_true", help="list the mutations and exit")
    parser.add_argument("--timeout", type=float, default=1200.0, help="seconds per mutation (default: 1200)")
    args = parser.parse_args(argv)
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    unknown = set(args.only or ()) - {m.name for m in MUTATIONS}
    if unknown:
        parser.error(f"unknown mutation(s) {', '.join(sorted(unknown))}; see --list")
    if args.list:
        for m in chosen:
            print(f"{m.name:40s} {m.path:36s} {m.why}")
        return 0
    results = []
    with tempfile.TemporaryDirectory(prefix="smarts-mutation-") as tmp:
        copy = Path(tmp)
        _copy_checkout(copy)
        for k, m in enumerate(chosen, 1):
            outcome, seconds, failed = _run(m, copy, args.full, args.timeout)
            results.append((m, outcome))
            print(f"[{k}/{len(chosen)}] {outcome:8s} {m.name:38s} {seconds:6.1f} s  {m.why}", flush=True)
            if failed:
                print(f"{'':14s}first failure: {failed}", flush=True)
    caught = sum(outcome == "caught" for _, outcome in results)
    print(f"\ncaught {caught} of {len(results)} mutations")
    for m, outcome in results:
        if outcome != "caught":
            print(f"  {outcome}: {m.name} ({m.path}): {m.why}")
    return 0 if caught == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
