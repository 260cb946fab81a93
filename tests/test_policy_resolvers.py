"""Policy resolvers: the env and the benchmark turn locators into policies through the resolver
they are given or the installed default (entry points), never by importing agents/ or zoo/; the
policies load without the trainer or the simulator."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import zoo.registry
from smarts.benchmark.jobs import plan_jobs
from smarts.benchmark.metrics import read_episode
from smarts.benchmark.runner import run_jobs
from smarts.benchmark.suites import load_suite
from smarts.core import policies
from smarts.core.policies import NoResolverError, default_resolver, resolve_policy
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec

ROOT = Path(__file__).resolve().parents[1]
TINY = str(ROOT / "tests" / "benchmark" / "tiny_suite.yaml")


class CreepPolicy:
    """Creeps straight ahead in RelativeTargetPose and counts its calls."""

    action_space = "relative_target_pose"

    def __init__(self):
        self.calls = 0

    def act(self, obs):
        self.calls += 1
        out = np.zeros((len(obs["ego"]), 3), dtype=np.float32)
        out[:, 0] = 0.5
        return out


def creep_resolver(locator: str, **kwargs):
    """``test:creep``, anything else from the installed resolvers (module level: it pickles)."""
    if locator == "test:creep":
        return CreepPolicy()
    return default_resolver(locator, **kwargs)


def test_the_env_drives_social_agents_with_the_resolver_it_is_given():
    asked = []

    def resolver(locator, **kwargs):
        asked.append(locator)
        return CreepPolicy()

    spec = make_spec([agent(offset=80.0, speed=0.0), agent(lane=1, offset=10.0, speed=5.0, policy="test:creep")])
    env = DrivingParallelEnv(spec, policy_resolver=resolver)
    env.reset(seed=0)
    row = env.sim.agent_row[1]
    start = float(env.sim.table.x[row])
    for _ in range(5):
        env.step({"agent_0": np.zeros(3)})
    policy = env.social.groups[0][0]
    assert asked == ["test:creep"] and isinstance(policy, CreepPolicy) and policy.calls == 5
    assert env.sim.table.x[row] > start + 1.0
    env.close()
    with pytest.raises(
        ValueError, match=r"agents\[1\]\.policy: unknown agent locator 'test:creep'; known: zoo:keep-lane"
    ):
        DrivingParallelEnv(spec)  # the installed default does not know it


def test_the_default_resolver_routes_by_scheme_and_lists_the_known_locators():
    assert policies.installed_entry_points()["zoo"].value == "zoo:make_policy"
    assert type(resolve_policy("zoo:keep-lane")).__name__ == "KeepLanePolicy"
    assert resolve_policy("keep-lane", dt=0.2).dt == 0.2  # a bare name goes to the default; options reach the policy
    checkpoint = zoo.registry.ZOO_DIR / "checkpoints" / "platoon-c.pt"
    assert resolve_policy(str(checkpoint)).action_space == "continuous"  # a path loads the file
    with pytest.raises(ValueError, match=r"unknown agent locator 'zoo:teleporter'; known: zoo:keep-lane, zoo:random"):
        resolve_policy("zoo:teleporter")
    with pytest.raises(ValueError, match=r"missing\.pt: no such checkpoint file"):
        resolve_policy("runs/missing.pt")


def test_without_installed_resolvers_the_error_says_how_to_get_them(monkeypatch):
    monkeypatch.setattr(policies, "installed_entry_points", lambda: {})
    with pytest.raises(NoResolverError, match=r"no policy resolver for 'zoo:keep-lane'.*pip install -e \."):
        resolve_policy("zoo:keep-lane")
    assert isinstance(resolve_policy("test:creep", creep_resolver), CreepPolicy)  # an explicit one still works


def test_the_runner_uses_the_resolver_it_is_given_in_worker_processes(tmp_path):
    suite = load_suite(TINY)
    with pytest.raises(ValueError, match="unknown agent locator 'test:creep'"):
        plan_jobs(["test:creep"], suite, 1, tmp_path / "a", references=False)  # refused before any episode
    jobs = plan_jobs(
        ["test:creep", "zoo:stand-still"], suite, 1, tmp_path, references=False, policy_resolver=creep_resolver
    )
    results = run_jobs(jobs, workers=2, progress=False, policy_resolver=creep_resolver)  # spawned workers
    assert [r["failure"] for r in results] == [None] * 4
    assert [r["agent"] for r in results] == ["test:creep"] * 2 + ["zoo:stand-still"] * 2
    log = read_episode(results[0]["log"])
    assert log.info["agent"] == "test:creep" and log.agents["agent_0"].speed[-1] > 4.0


def test_checkpoints_and_zoo_agents_load_without_the_trainer_or_the_simulator(tmp_path):
    """An exported SB3 policy, a torchrl checkpoint and a zoo agent, in a fresh interpreter: neither
    ``train`` nor ``smarts`` is imported, and the SB3 policy acts as SB3 itself does."""
    import gymnasium as gym
    import torch
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    from agents.sb3_policy import SB3_FORMAT

    shapes = {"ego": [4], "lead": [2, 3]}
    space = gym.spaces.Dict({k: gym.spaces.Box(-np.inf, np.inf, tuple(v), np.float32) for k, v in shapes.items()})
    sb3 = MultiInputActorCriticPolicy(
        space, gym.spaces.Box(-1.0, 1.0, (2,), np.float32), lambda _: 0.0, net_arch=[8, 8]
    )
    low, high = [-1.0, -2.0], [1.0, 2.0]
    blob = {"format": SB3_FORMAT, "policy": sb3.state_dict(), "observation": shapes, "interface": {"lead": True},
            "lane_relative": {"max_jerk": 0.5}, "net_arch": [8, 8], "config": {}, "step": 0,
            "action": {"space": "relative_target_pose", "controller": "lane_relative", "low": low, "high": high}}  # fmt: skip
    torch.save(blob, tmp_path / "sb3.pt")
    obs = {"ego": np.linspace(-1, 1, 12, dtype=np.float32).reshape(3, 4), "lead": np.ones((3, 2, 3), np.float32)}
    np.savez(tmp_path / "obs.npz", **obs)
    code = """
import json, sys
import numpy as np
from agents.loader import load_policy_file
from zoo import make_policy
sb3 = load_policy_file(sys.argv[1])
obs = dict(np.load(sys.argv[2]))
ppo = make_policy("zoo:platoon-c")
keep = make_policy("zoo:keep-lane")
print(json.dumps({"action": sb3.act(obs).tolist(), "setup": [sb3.action_space, sb3.controller, sb3.interface,
    sb3.lane_relative], "ppo": ppo.action_space, "keep": keep.action_space,
    "loaded": sorted({m.split(".")[0] for m in sys.modules} & {"train", "smarts"})}))
"""
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "sb3.pt"), str(tmp_path / "obs.npz")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["loaded"] == []
    assert out["setup"] == ["relative_target_pose", "lane_relative", {"lead": True}, {"max_jerk": 0.5}]
    assert (out["ppo"], out["keep"]) == ("continuous", "relative_target_pose")
    expected, _ = sb3.predict(obs, deterministic=True)
    expected = np.array(low) + (np.clip(expected, -1, 1) + 1) * 0.5 * (np.array(high) - np.array(low))
    np.testing.assert_allclose(out["action"], expected, rtol=1e-5, atol=1e-6)


def test_a_folder_named_like_the_zoo_in_the_current_directory_is_named_in_the_error(tmp_path):
    """``python -m`` looks in the current directory first: an output folder ``zoo/`` there hides an
    editable install's zoo package. Either the installed zoo still loads (a regular install wins
    over a bare folder) or the error names the folder; never the bare ``has no attribute``."""
    (tmp_path / "zoo").mkdir()
    code = (
        "from smarts.core.errors import NoResolverError\n"
        "from smarts.core.policies import default_resolver\n"
        "try:\n"
        "    print('loaded', default_resolver('zoo:keep-lane').action_space)\n"
        "except NoResolverError as err:\n"
        "    print('refused', err)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    if done.stdout.startswith("refused"):
        assert str(tmp_path / "zoo") in done.stdout and "hides the installed one" in done.stdout
        assert "run from another directory or rename that folder" in done.stdout
    else:
        assert done.stdout.strip() == "loaded relative_target_pose"
