"""The worker pool of the batched env: workers write their slots' observations and flags into one
shared-memory buffer that this process reads in place, and the buffer goes with the env."""

import os
from pathlib import Path

import numpy as np
import pytest

from smarts.benchmark.suites import load_suite
from smarts.core.errors import ActionError
from smarts.env.batched import BatchedDriving
from smarts.env.batched.driving import SharedArrays
from smarts.scenario import load_scenario
from smarts.sensors.observation import ObservationConfig


def _specs(*names: str) -> list:
    suite = {s.name: s.spec for s in load_suite("adaptive").scenarios}
    return [suite[n] for n in names]


def _segments() -> set[str]:
    shm = Path("/dev/shm")
    return {p.name for p in shm.iterdir()} if shm.is_dir() else set()


def test_workers_write_into_one_shared_buffer_read_in_place_and_freed_on_close():
    before = _segments()
    specs = _specs("a01_straight_free", "a02_straight_two_followers_low", "a01_straight_free")
    env = BatchedDriving(specs, workers=2)
    here = BatchedDriving(specs)
    try:
        assert [shard.rows for shard in env.shards] == [slice(0, 3), slice(3, 4)]  # contiguous blocks of rows
        name = env._buffer.name
        if os.path.isdir("/dev/shm"):
            assert name.lstrip("/") in _segments()
        env.set_seed(5)
        here.set_seed(5)
        obs, mine = env.reset(), here.reset()
        for key in obs:
            assert obs[key] is env._buffer.arrays[f"obs/{key}"]  # the shared rows themselves, no copy
            np.testing.assert_array_equal(obs[key], mine[key])
        rng = np.random.default_rng(0)
        for _ in range(60):
            actions = rng.uniform(-1.0, 1.0, size=(env.num_slots, env.action_width))
            a, b = env.step(actions), here.step(actions)
            for key in a.obs:
                np.testing.assert_array_equal(a.obs[key], b.obs[key])
            for field in ("reward", "terminated", "truncated", "acted", "restarted"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    finally:
        env.close()
        here.close()
    # The block is unlinked with the env (other tests running beside this one may make their own).
    assert name.lstrip("/") not in _segments() and name.lstrip("/") not in before


def test_shared_arrays_attach_by_name_to_the_same_memory():
    layout = {"obs/x": ((4, 3), "<f4"), "reward": ((4,), "<f4"), "acted": ((4,), "|b1")}
    owner = SharedArrays(layout)
    other = SharedArrays(layout, owner.name)
    try:
        other.arrays["obs/x"][2] = [1.0, 2.0, 3.0]
        other.arrays["acted"][1] = True
        np.testing.assert_array_equal(owner.group("obs")["x"][2], [1.0, 2.0, 3.0])
        assert owner.arrays["acted"].tolist() == [False, True, False, False]
        assert all(v.ctypes.data % SharedArrays.ALIGN == 0 for v in owner.arrays.values())
    finally:
        other.release()
        owner.release(unlink=True)


@pytest.mark.parametrize("with_sumo", [False, True])
def test_stepping_in_two_parts_gives_what_stepping_all_slots_at_once_gives(with_sumo):
    """With the copies in two workers, ``begin_step``/``end_step`` step each worker's slots apart
    (a caller acts for one part while the other steps); every slot sees the same observations,
    rewards, ends and restarts as with ``step``, and misuse is refused by name. A SUMO copy (a
    worker of its own) makes the second part beside one worker of the rest."""
    specs = _specs("a01_straight_free", "a02_straight_two_followers_low", "a01_straight_free", "a01_straight_free")
    options: dict = {}
    if with_sumo:
        specs = [load_scenario("highway_merge_traffic"), *specs[:2]]
        options = {"observation": ObservationConfig()}  # one interface for the SUMO scenario and the suite's
    parted = BatchedDriving(specs, workers=1 if with_sumo else 2, **options)
    whole = BatchedDriving(specs, **options)
    try:
        assert len(whole.parts) == 1 and len(parted.parts) == 2
        ids = [np.arange(parted.num_slots)[rows] for rows in parted.parts]
        assert sorted(np.concatenate(ids).tolist()) == list(range(parted.num_slots))
        parted.set_seed(9)
        whole.set_seed(9)
        parted.reset(), whole.reset()
        rng = np.random.default_rng(1)
        restarts = 0
        for _ in range(400 if with_sumo else 120):
            actions = rng.uniform(-1.0, 1.0, size=(whole.num_slots, whole.action_width))
            for p, rows in enumerate(parted.parts):
                parted.begin_step(actions[rows], p)
            got = [parted.end_step(p) for p in range(len(parted.parts))]
            want = whole.step(actions)
            for rows, res in zip(parted.parts, got):
                for key in res.obs:
                    np.testing.assert_array_equal(res.obs[key], want.obs[key][rows])
                for field in ("reward", "terminated", "truncated", "acted", "restarted"):
                    np.testing.assert_array_equal(getattr(res, field), getattr(want, field)[rows])
                again = res.restarted
                for key in res.first:
                    np.testing.assert_array_equal(res.first[key][again], want.first[key][rows][again])
            restarts += int(want.restarted.sum())
        assert restarts > 0  # copies ended and restarted in between
        parted.begin_step(actions[parted.parts[0]], 0)
        with pytest.raises(RuntimeError, match="part 0 is already stepping"):
            parted.begin_step(actions[parted.parts[0]], 0)
        with pytest.raises(RuntimeError, match="while a part is stepping"):
            parted.step(actions)
        with pytest.raises(RuntimeError, match="part 1 was not begun"):
            parted.end_step(1)
        with pytest.raises(ActionError, match="actions of part 1: expected shape"):
            parted.begin_step(actions, 1)
    finally:
        parted.close()  # with part 0 still stepping: the worker's answer is taken, then it closes
        whole.close()
