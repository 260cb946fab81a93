"""Every backend and batch size against the golden trajectories (``tests/golden/golden.json``).

The golden file holds per-step digests of the vehicle table, observations, rewards and events of
every golden case (``tests.golden.cases``) and seed, recorded with ``python -m tests.golden.record``.
An episode must give the same bits alone (the per-env backend), among the copies of its own case
(B = 3, one per seed) and among every case the batched backend runs (one simulation of many maps).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.golden.cases import MAX_STEPS, SEEDS, all_cases
from tests.golden.record import GOLDEN
from tests.golden.run import STREAMS, run_batched, run_engine, run_single

CASES = {c.name: c for c in all_cases()}
GOLD = json.loads(GOLDEN.read_text())

NOT_BATCHED = {name for name, c in CASES.items() if c.sumo}
"""SUMO cases: libsumo holds one simulation per process, so they run in worker processes."""


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("golden")


def _specs(work: Path, name: str):
    return CASES[name].load(work)


def test_the_golden_file_covers_every_case_and_seed():
    assert GOLD["max_steps"] == MAX_STEPS
    assert sorted(GOLD["cases"]) == sorted(CASES)
    for name, episodes in GOLD["cases"].items():
        assert sorted(episodes) == sorted(str(s) for s in SEEDS), name


@pytest.mark.parametrize("name", sorted(CASES))
def test_single_episodes_match_the_golden_trajectories(name, work):
    spec = _specs(work, name)
    problems = {}
    for seed in SEEDS:
        diff = run_single(spec, seed).first_difference(GOLD["cases"][name][str(seed)])
        if diff is not None:
            problems[seed] = diff
    assert not problems, f"{name}: seeds differ from the golden trajectories: {problems}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_batched_copies_of_one_case_match_the_golden_trajectories(name, work):
    """Three copies (one per seed) in one batched env: one simulation, or for SUMO one worker
    process each (whose tables this process cannot hash: observations, rewards and events)."""
    spec = _specs(work, name)
    records = run_batched([spec] * len(SEEDS), list(SEEDS))
    streams = ("obs", "reward", "events") if CASES[name].sumo else STREAMS
    problems = {}
    for seed, record in zip(SEEDS, records):
        diff = record.first_difference(GOLD["cases"][name][str(seed)], streams)
        if diff is not None:
            problems[seed] = diff
    assert not problems, f"{name}: batched copies differ from the golden trajectories: {problems}"


def test_one_simulation_of_every_batched_case_matches_the_golden_trajectories(work):
    """Every case but SUMO's in one simulation of the env engine (maps, sensors, action spaces,
    social agents, V2V, replay all mixed), each episode as it runs alone."""
    names = sorted(set(CASES) - NOT_BATCHED)
    specs = [_specs(work, n) for n in names]
    seeds = [SEEDS[i % len(SEEDS)] for i in range(len(names))]
    records = run_engine(specs, seeds)
    problems = {}
    for name, seed, record in zip(names, seeds, records):
        diff = record.first_difference(GOLD["cases"][name][str(seed)])
        if diff is not None:
            problems[f"{name} seed {seed}"] = diff
    assert not problems, f"episodes differ from the golden trajectories in one simulation: {problems}"


def test_sumo_copies_in_workers_step_beside_one_simulation_of_the_rest(work):
    """SUMO copies in worker processes and built-in copies in one simulation, in one batched env:
    every episode as it runs alone."""
    names = ["library/highway_merge_traffic", "library/intersection_4way_signal_traffic", "readme/readme_sumo_pedestrians",
             "collaborative/c07_4way_3lane_signal_three_turns_high", "feature/feature_target_pose"]  # fmt: skip
    specs = [_specs(work, n) for n in names]
    seeds = [SEEDS[i % len(SEEDS)] for i in range(len(names))]
    records = run_batched(specs, seeds)
    problems = {}
    for name, seed, record in zip(names, seeds, records):
        streams = ("obs", "reward", "events") if CASES[name].sumo else STREAMS
        diff = record.first_difference(GOLD["cases"][name][str(seed)], streams)
        if diff is not None:
            problems[f"{name} seed {seed}"] = diff
    assert not problems, f"copies differ from the golden trajectories: {problems}"
