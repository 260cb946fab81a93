"""The two library adapters over the one batched core: a SUMO copy (in a worker process of its
own) beside built-in ones, each slot playing what the copy's single env plays with the one seeding
rule, and both adapters playing the same episodes."""

import numpy as np
import torch
from torchrl.envs.utils import check_env_specs

from smarts.core.simulation import derived_seed
from smarts.env import DrivingParallelEnv
from smarts.env.assembly import as_spec
from smarts.env.batched.driving import COPY_SEED_STRIDE, is_sumo
from smarts.env.sb3_vec_env import SmartsVecEnv
from smarts.env.torchrl_env import SmartsBatchedEnv
from smarts.scenario import replace

SEED = 3
STEPS = 24  # the SUMO copy's episode is 15 steps: one restart within the run


def _specs() -> list:
    """Two built-in copies around one SUMO copy whose episode is cut short (so it restarts)."""
    sumo = replace(as_spec("highway_merge_traffic"), episode_steps=15)
    cruise = as_spec("straight_2lane_cruise")
    assert is_sumo(sumo) and not is_sumo(cruise)
    return [cruise, sumo, cruise]


def _commands(slots: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [
        rng.uniform([0.5, -0.05, -0.02], [1.5, 0.05, 0.02], size=(slots, 3)).astype(np.float32) for _ in range(STEPS)
    ]


def _single_env_episodes(spec, copy: int, slot_of: dict, commands: list) -> list[dict]:
    """Per step, the observations (by slot) the copy's single env gives with the rule's seeds and
    the slots' commands: ``{"obs": {slot: ego}, "reward": {slot: r}, "first": {slot: ego}}``."""
    env = DrivingParallelEnv(spec)
    try:
        episode = 0
        obs, _ = env.reset(seed=derived_seed(SEED, copy * COPY_SEED_STRIDE))
        out = [{"obs": {slot_of[a]: o["ego"].copy() for a, o in obs.items()}}]
        for step in commands:
            obs, rewards, *_ = env.step({a: step[slot_of[a]] for a in env.agents})
            row = {"obs": {slot_of[a]: o["ego"].copy() for a, o in obs.items()},
                   "reward": {slot_of[a]: r for a, r in rewards.items()}}  # fmt: skip
            if not env.agents:
                episode += 1
                first, _ = env.reset(seed=derived_seed(SEED, copy * COPY_SEED_STRIDE + episode))
                row["first"] = {slot_of[a]: o["ego"].copy() for a, o in first.items()}
            out.append(row)
        return out
    finally:
        env.close()


def test_a_sumo_copy_beside_built_in_ones_plays_its_single_env_in_both_adapters():
    specs = _specs()
    tr = SmartsBatchedEnv(specs)
    vec = SmartsVecEnv(specs, seed=SEED)
    try:
        assert len(tr.driving.shards) == 1 and tr.driving.shards[0].copies == [1]  # SUMO in its worker
        assert (
            tr.slots
            == vec.slot_agents
            == [(0, "agent_0"), (0, "agent_1"), (1, "agent_0"), (2, "agent_0"), (2, "agent_1")]
        )
        check_env_specs(tr)
        slot_of = {key: j for j, key in enumerate(vec.slot_agents)}
        commands = _commands(len(slot_of))
        expected = [
            _single_env_episodes(spec, i, {a.id: slot_of[(i, a.id)] for a in spec.agents if not a.is_social}, commands)
            if not is_sumo(spec) else None
            for i, spec in enumerate(specs)
        ]  # fmt: skip
        tr.set_seed(SEED)
        td = tr.reset()
        obs = vec.reset()
        np.testing.assert_array_equal(td["observation", "ego"].numpy(), obs["ego"])
        restarts = 0
        for t, step in enumerate(commands, start=1):
            td = tr.step(td.set("action", torch.from_numpy(step)))
            obs, rewards, dones, infos = vec.step(step)
            nxt = td["next"]
            np.testing.assert_array_equal(nxt["reward"][:, 0].numpy(), rewards, err_msg=f"step {t}")
            np.testing.assert_array_equal(nxt["done"][:, 0].numpy(), dones, err_msg=f"step {t}")
            for i, per_step in enumerate(expected):
                if per_step is None:
                    continue
                row = per_step[t]
                for j, ego in row["obs"].items():
                    np.testing.assert_array_equal(
                        nxt["observation", "ego"][j].numpy(), ego, err_msg=f"step {t} slot {j}"
                    )
                    assert rewards[j] == np.float32(row["reward"][j])
            sumo = slot_of[(1, "agent_0")]
            if dones[sumo]:  # the SUMO copy restarted within the step (SB3) / waits for torchrl's reset
                restarts += 1
                assert infos[sumo]["TimeLimit.truncated"] and infos[sumo]["episode"]["l"] == 15
                np.testing.assert_array_equal(
                    infos[sumo]["terminal_observation"]["ego"], nxt["observation", "ego"][sumo].numpy()
                )
            td = tr.step_mdp(td)
            if td["done"].any():
                td = tr.reset(td.set("_reset", td["done"].clone()))
            # After torchrl's reset both adapters hold the same observations (the new episodes' first).
            np.testing.assert_array_equal(td["observation", "ego"].numpy(), obs["ego"], err_msg=f"step {t}")
        assert restarts == 1
    finally:
        tr.close()
        vec.close()


def test_the_sumo_copy_in_its_worker_plays_its_single_env():
    """The SUMO copy's slot against ``DrivingParallelEnv`` of the same scenario and the rule's seed
    (compared in this process, whose own libsumo is free: the batch's SUMO runs in the worker)."""
    specs = _specs()
    vec = SmartsVecEnv(specs, seed=SEED)
    sumo = vec.slot_agents.index((1, "agent_0"))
    commands = _commands(vec.num_envs)
    try:
        got = [vec.reset()["ego"][sumo].copy()]
        for step in commands:
            obs, rewards, dones, infos = vec.step(step)
            got.append((obs["ego"][sumo].copy(), rewards[sumo], infos[sumo].get("terminal_observation")))
    finally:
        vec.close()
    expected = _single_env_episodes(specs[1], 1, {"agent_0": sumo}, commands)
    np.testing.assert_array_equal(got[0], expected[0]["obs"][sumo])
    for t in range(1, len(got)):
        ego, reward, terminal = got[t]
        row = expected[t]
        assert reward == np.float32(row["reward"][sumo]), t
        if "first" in row:  # the episode ended: SB3 sees the final observation in info, the first in obs
            np.testing.assert_array_equal(terminal["ego"], row["obs"][sumo])
            np.testing.assert_array_equal(ego, row["first"][sumo])
        else:
            np.testing.assert_array_equal(ego, row["obs"][sumo])
    assert any("first" in row for row in expected[1:])
