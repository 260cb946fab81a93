"""The zoo: every locator builds a policy that acts on the env's observations."""

import gymnasium
import numpy as np
import pytest

import smarts.env  # noqa: F401
from zoo import ZOO, make_policy


@pytest.mark.parametrize("name", sorted(ZOO))
def test_every_zoo_agent_acts_in_its_action_space(name):
    policy = make_policy(f"zoo:{name}")
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise")
    obs, _ = env.reset(seed=0)
    action = np.asarray(policy.act({k: v[None] for k, v in obs.items()}))
    assert action.shape == (1, 3) and np.isfinite(action).all()
    assert policy.action_space in ("relative_target_pose", "continuous")


def test_zoo_cards_exist_for_checkpoints():
    from pathlib import Path

    import zoo.registry as registry

    for name, (module, target, _) in ZOO.items():
        if module == registry.CHECKPOINT:
            assert (registry.ZOO_DIR / target).is_file()
            card = registry.ZOO_DIR / "cards" / f"{name}.md"
            assert "S_bench" in card.read_text() and Path(target).stem == name


def test_unknown_locator_lists_the_known_ones():
    with pytest.raises(ValueError, match="zoo:keep-lane"):
        make_policy("zoo:teleporter")
