"""``agents.checked``: a checkpoint whose bytes passed the checks before gives its settings without
torch, drives exactly as when loaded, and anything changed or unreadable is loaded and checked
in full."""

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import zoo.registry
from agents.checked import CheckedPolicy, load_checkpoint_policy
from agents.checkpoint import CheckpointError
from smarts.benchmark.agents import policy_files_digest, policy_setup

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = Path(zoo.registry.ZOO_DIR) / "checkpoints"
POLICIES = ["platoon-rtp.pt", "platoon-c.pt", "drive.pt"]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "checked-checkpoints"


@pytest.mark.parametrize("name", POLICIES)
def test_a_checked_file_gives_the_same_settings_and_actions(cache, name):
    first = load_checkpoint_policy(SHIPPED / name)
    assert not isinstance(first, CheckedPolicy) and len(list(cache.glob("*.json"))) == 1
    again = load_checkpoint_policy(SHIPPED / name)
    assert isinstance(again, CheckedPolicy) and again._policy is None
    assert repr(policy_setup(again, name)) == repr(policy_setup(first, name))
    assert again.batching == first.batching and policy_files_digest(again) == policy_files_digest(first)
    assert not hasattr(again, "seed") and again._policy is None  # what the policy lacks needs no load
    space = {k: np.zeros(shape, np.float32) for k, shape in zip(first.layout.keys, first.layout.shapes)}
    obs = {k: np.random.default_rng(0).normal(size=(3, *v.shape)).astype(np.float32) for k, v in space.items()}
    assert np.array_equal(again.act(obs), first.act(obs))  # loaded (and checked) on first use
    assert again._policy is not None and "act" in vars(again)  # the bound method kept for the next call
    assert isinstance(pickle.loads(pickle.dumps(again)), CheckedPolicy)


def test_planning_with_a_checked_file_does_not_import_torch(cache, tmp_path):
    load_checkpoint_policy(SHIPPED / "platoon-rtp.pt")  # checked once (this process has torch)
    code = (
        "import sys\n"
        "from smarts.benchmark.agents import load_policy, policy_setup\n"
        "from smarts.benchmark.batching import batching_mode\n"
        "p = load_policy('zoo:platoon-rtp')\n"
        "print(policy_setup(p, 'zoo:platoon-rtp').action_space, batching_mode(p), 'torch' in sys.modules)\n"
    )
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "SMARTS_CACHE_DIR": str(cache.parent)}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["relative_target_pose", "episodes", "False"]


def test_a_changed_file_or_a_damaged_entry_is_checked_in_full(cache, tmp_path):
    good = tmp_path / "policy.pt"
    good.write_bytes((SHIPPED / "platoon-rtp.pt").read_bytes())
    load_checkpoint_policy(good)
    assert isinstance(load_checkpoint_policy(good), CheckedPolicy)
    blob = torch.load(good, weights_only=True)
    blob["action"]["low"][0] = float("nan")  # other bytes at the same path: refused, never remembered
    torch.save(blob, good)
    for _ in range(2):
        with pytest.raises(CheckpointError, match="action.low"):
            load_checkpoint_policy(good)
    assert len(list(cache.glob("*.json"))) == 1
    (entry,) = cache.glob("*.json")
    entry.write_text('{"settings": {"action_space": "teleport"}}')  # not an entry: loaded in full
    good.write_bytes((SHIPPED / "platoon-rtp.pt").read_bytes())
    assert not isinstance(load_checkpoint_policy(good), CheckedPolicy)
    with pytest.raises(CheckpointError):
        load_checkpoint_policy(tmp_path / "missing.pt")


def test_entries_unused_for_a_month_are_removed_as_others_are_written(cache, tmp_path):
    import os
    import time

    load_checkpoint_policy(SHIPPED / "platoon-rtp.pt")
    (kept,) = cache.glob("*.json")
    long_ago = time.time() - 40 * 86400
    os.utime(kept, (long_ago, long_ago))
    assert isinstance(load_checkpoint_policy(SHIPPED / "platoon-rtp.pt"), CheckedPolicy)  # used: kept
    os.utime(kept, (long_ago, long_ago))
    load_checkpoint_policy(SHIPPED / "drive.pt")  # another entry written: the unused one goes
    assert not kept.exists() and len(list(cache.glob("*.json"))) == 1
