import numpy as np
import pytest

from smarts.core.vehicle_table import Role
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec


def test_a_social_agent_is_driven_by_its_zoo_policy_and_hidden_from_the_learner():
    spec = make_spec(
        [agent(lane=0, offset=80.0, speed=0.0), agent(lane=0, offset=10.0, speed=10.0, policy="zoo:keep-lane")],
        events={"terminate_on": ["collision", "off_road"]},
    )
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    assert env.possible_agents == ["agent_0"] and list(obs) == ["agent_0"]
    sim = env.sim
    assert sim.table.role[sim.agent_row[1]] == Role.SOCIAL_AGENT
    for _ in range(150):  # the learner stands still; the social agent drives up and stops behind
        obs, rewards, terms, truncs, infos = env.step({"agent_0": np.zeros(3)})
        assert not terms["agent_0"]
    gap = sim.table.x[sim.agent_row[0]] - sim.table.x[sim.agent_row[1]] - sim.table.length[0]
    assert 1.0 < gap < 6.0 and sim.table.speed[sim.agent_row[1]] < 0.1
    # The learner sees the social agent as its neighbour behind it.
    assert obs["agent_0"]["neighbour_mask"][0] == 1 and obs["agent_0"]["neighbours"][0, 0] < 0


def test_unknown_policy_locator_is_a_clear_error():
    spec = make_spec([agent(), agent(lane=1, policy="zoo:no-such-agent")])
    with pytest.raises(ValueError, match=r"agents\[1\]\.policy: unknown agent locator 'zoo:no-such-agent'"):
        DrivingParallelEnv(spec)
