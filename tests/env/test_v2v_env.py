"""V2V messaging through the envs: the message part of actions, received messages in observations."""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test

from smarts.dynamics.action_spaces import ActionError
from smarts.env import DrivingEnv, DrivingParallelEnv
from smarts.scenario import ScenarioError, ScenarioSpec, load_scenario, read_scenario, replace, scenario_to_dict
from tests.builders import agent, make_spec

CRUISE = np.array([1.0, 0.0, 0.0])  # relative pose: 1 m straight ahead per step
LANE_WIDTH = 3.2


def _spec(comms: dict, agents=None, **extra) -> ScenarioSpec:
    """agent_0 in lane 0 at 10 m, agent_1 in lane 1 at 30 m, on the straight two-lane road."""
    agents = agents or [agent(lane=0, offset=10.0), agent(lane=1, offset=30.0)]
    return make_spec(agents, comms=comms, **extra)


def _act(payload, channel=None) -> np.ndarray:
    tail = [] if channel is None else [channel]
    return np.concatenate([CRUISE, payload, tail])


def _senders(obs: dict, agent_id: str) -> list[tuple[float, ...]]:
    """(from_agent, from_traffic, payload_0) of each message an agent received."""
    o = obs[agent_id]
    rows = o["messages"][o["message_mask"] > 0]
    return [(float(r[0]), float(r[1]), float(r[6])) for r in rows]


def test_without_comms_the_spaces_are_unchanged():
    env = DrivingParallelEnv(_spec(None))
    assert env.comms is None
    assert env.action_space("agent_0").shape == (3,)
    assert "messages" not in env.observation_space("agent_0").spaces
    obs, infos = env.reset(seed=0)
    assert "messages" not in obs["agent_0"] and infos["agent_0"] == {}


def test_a_payload_reaches_the_other_agent_after_the_latency_with_the_senders_pose():
    env = DrivingParallelEnv(_spec({"message_size": 2, "latency": 2, "range": 50}))
    space = env.action_space("agent_0")
    assert space.shape == (5,) and space.low[3:].tolist() == [-1, -1] and space.high[3:].tolist() == [1, 1]
    messages = env.observation_space("agent_1")["messages"]
    assert messages.shape == (8, 8)  # max_messages x (6 features + 2 payload floats)
    obs, infos = env.reset(seed=0)
    assert obs["agent_1"]["message_mask"].sum() == 0 and infos["agent_1"]["messages_received"] == 0
    sim = env.sim
    quiet = np.zeros(2)
    for step in range(1, 4):
        payload = np.array([0.5, -0.25]) if step == 1 else quiet
        obs, _, _, _, infos = env.step({"agent_0": _act(payload), "agent_1": _act(quiet)})
        if step == 1:
            sent_from = sim.table.data[:3, sim.agent_row[0]].copy()  # x, y, heading when sent
        if step < 3:  # sent at step 1, delivered at step 1 + latency
            assert obs["agent_1"]["message_mask"].sum() == 0
    o = obs["agent_1"]
    assert o["message_mask"].tolist() == [1, 0, 0, 0, 0, 0, 0, 0]
    assert infos["agent_1"]["messages_received"] == 1 and env.observation_space("agent_1").contains(o)
    first = o["messages"][0]
    # From agent_0 (10 m + 1 m at step 1) to agent_1 now (30 m + 3 m), one lane to the right.
    np.testing.assert_allclose(first[:6], [1, 0, -22.0, -LANE_WIDTH, 0.0, 2], atol=1e-4)
    np.testing.assert_allclose(first[6:], [0.5, -0.25])
    x, y, h = sim.table.data[:3, sim.agent_row[1]]
    dx, dy = sent_from[0] - x, sent_from[1] - y
    np.testing.assert_allclose(
        first[2:4], [np.cos(h) * dx + np.sin(h) * dy, -np.sin(h) * dx + np.cos(h) * dy], atol=1e-4
    )
    # agent_0 hears agent_1's (zero) message sent 18 m ahead of where agent_0 is now, one lane left.
    np.testing.assert_allclose(obs["agent_0"]["messages"][0, :6], [1, 0, 18.0, LANE_WIDTH, 0, 2], atol=1e-4)


def test_nothing_arrives_out_of_range():
    env = DrivingParallelEnv(_spec({"message_size": 1, "latency": 1, "range": 15}))
    env.reset(seed=0)
    for _ in range(5):
        obs, *_ = env.step({"agent_0": _act([1.0]), "agent_1": _act([1.0])})
        assert obs["agent_0"]["message_mask"].sum() == 0 and obs["agent_1"]["message_mask"].sum() == 0


def test_channels_isolate_and_the_action_can_pick_the_channel():
    agents = [agent(lane=0, offset=10.0), agent(lane=1, offset=20.0), agent(lane=0, offset=30.0)]
    agents[2]["interface"] = {"lidar": {"rays": 8}}  # a second interface group: merged by index
    fixed = _spec({"message_size": 1, "channels": 2, "agent_channels": {"agent_1": 1}}, agents)
    env = DrivingParallelEnv(fixed)
    env.reset(seed=0)
    obs, *_ = env.step({"agent_0": _act([0.1]), "agent_1": _act([0.2]), "agent_2": _act([0.3])})
    assert sorted(_senders(obs, "agent_0")) == [(1, 0, pytest.approx(0.3))]
    assert sorted(_senders(obs, "agent_2")) == [(1, 0, pytest.approx(0.1))]
    assert _senders(obs, "agent_1") == []  # alone on channel 1
    assert "lidar" in obs["agent_2"] and env.observation_space("agent_2").contains(obs["agent_2"])

    picked = _spec({"message_size": 1, "channels": 3, "channel_action": True}, agents)
    env = DrivingParallelEnv(picked)
    assert env.action_space("agent_0").high[-1] == 2.0
    env.reset(seed=0)
    obs, *_ = env.step({"agent_0": _act([0.1], 2.2), "agent_1": _act([0.2], 1.6), "agent_2": _act([0.3], 0)})
    # Channels 2, 2 (1.6 rounds to 2) and 0: agent_2 is alone.
    assert _senders(obs, "agent_0") == [(1, 0, pytest.approx(0.2))]
    assert _senders(obs, "agent_1") == [(1, 0, pytest.approx(0.1))]
    assert _senders(obs, "agent_2") == []
    obs, *_ = env.step({"agent_0": _act([0.1], 0), "agent_1": _act([0.2], 0), "agent_2": _act([0.3], 0)})
    assert sorted(_senders(obs, "agent_2")) == [(1, 0, pytest.approx(0.1)), (1, 0, pytest.approx(0.2))]


def test_connected_traffic_is_heard_from_reset_and_social_agents_only_listen():
    trip = {"id": "lead", "route": ["main"], "depart": 0, "depart_lane": 0, "depart_pos": 40, "depart_speed": 5}
    agents = [agent(lane=0, offset=10.0), agent(lane=1, offset=20.0, policy="zoo:keep-lane")]
    spec = _spec({"message_size": 3, "penetration": 1.0}, agents, traffic={"engine": "builtin", "trips": [trip]})
    env = DrivingParallelEnv(spec)
    obs, infos = env.reset(seed=0)
    assert env.possible_agents == ["agent_0"] and infos["agent_0"]["messages_received"] == 1
    sim = env.sim
    lead = sim.table.row_of["lead"]
    traffic_msg = obs["agent_0"]["messages"][0]
    assert traffic_msg[:2].tolist() == [0, 1]  # from traffic, latency 0: heard at reset
    np.testing.assert_allclose(traffic_msg[6:], sim.table.data[:3, lead], atol=1e-3)  # its x, y, heading
    obs, _, _, _, infos = env.step({"agent_0": _act([0.7, 0.7, 0.7])})
    assert [s[:2] for s in _senders(obs, "agent_0")] == [(0, 1)]  # nothing from the social agent
    last = env.driving._social_obs  # the social agent's (agent 1) last observation heard the learner
    heard = last["messages"][1][last["message_mask"][1] > 0]
    assert sorted(heard[:, :2].tolist()) == [[0, 1], [1, 0]]
    np.testing.assert_allclose(heard[heard[:, 0] == 1][0, 6:], [0.7, 0.7, 0.7], rtol=1e-6)


def test_bad_message_actions_raise_naming_the_agent_before_anything_moves():
    env = DrivingParallelEnv(_spec({"message_size": 2}))
    env.reset(seed=0)
    before, step = env.sim.table.x.copy(), env.sim.step_count
    with pytest.raises(ActionError, match=r"agent_1: message action component payload_1 is nan") as err:
        env.step({"agent_0": _act([0.0, 0.0]), "agent_1": _act([0.0, np.nan])})
    assert err.value.agent_ids == ["agent_1"]
    with pytest.raises(ActionError, match=r"agent_0: action has shape \(3,\); expected shape \(5,\): 3 driving") as err:
        env.step({"agent_0": CRUISE, "agent_1": _act([0.0, 0.0])})
    assert err.value.agent_ids == ["agent_0"]
    np.testing.assert_array_equal(env.sim.table.x, before)
    assert env.sim.step_count == step
    # A NaN in the driving part is still the driving check's error.
    with pytest.raises(ActionError, match=r"agent_0.*dx is nan"):
        env.step({"agent_0": np.array([np.nan, 0, 0, 0, 0]), "agent_1": _act([0.0, 0.0])})


def test_agents_with_different_driving_spaces_get_their_own_action_widths():
    agents = [agent(lane=0, offset=10.0), agent(lane=1, offset=20.0, action_space="lane")]
    env = DrivingParallelEnv(_spec({"message_size": 2, "latency": 0}, agents))
    assert env.action_space("agent_0").shape == (5,) and env.action_space("agent_1").shape == (4,)
    env.reset(seed=0)
    obs, *_ = env.step({"agent_0": _act([0.1, 0.2]), "agent_1": np.array([10.0, 0.0, 0.3, 0.4])})
    assert _senders(obs, "agent_0") == [(1, 0, pytest.approx(0.3))]
    assert _senders(obs, "agent_1") == [(1, 0, pytest.approx(0.1))]
    with pytest.raises(ActionError, match=r"agent_1: action has shape \(5,\); expected shape \(4,\)"):
        env.step({"agent_0": _act([0.1, 0.2]), "agent_1": np.zeros(5)})


def test_same_seed_same_deliveries():
    spec = load_scenario("intersection_v2v")
    spec = replace(spec, comms=replace(spec.comms, loss=0.3))

    def run(seed: int) -> list[np.ndarray]:
        env = DrivingParallelEnv(spec)
        rng = np.random.default_rng(0)
        obs, _ = env.reset(seed=seed)
        out = [obs[a]["messages"].copy() for a in sorted(obs)]
        for _ in range(30):
            actions = {a: np.concatenate([[0.8, 0.0, 0.0], rng.uniform(-1, 1, 8)]) for a in env.agents}
            obs, *_ = env.step(actions)
            out += [obs[a]["messages"].copy() for a in sorted(obs)]
        env.close()
        return out

    first, again = run(3), run(3)
    assert len(first) == len(again) and all(np.array_equal(a, b) for a, b in zip(first, again))
    assert sum(int(m[:, 1].sum()) for m in first) > 0  # connected traffic was heard
    other = run(4)
    assert not all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(first, other))


def test_pettingzoo_api_with_comms():
    env = DrivingParallelEnv("intersection_v2v")
    parallel_api_test(env, num_cycles=60)
    env.close()


def test_gymnasium_check_env_with_comms_on_one_agent():
    spec = load_scenario("intersection_v2v")
    spec = replace(spec, comms=replace(spec.comms, agent_channels={"agent_2": 0}))
    env = DrivingEnv(spec, agent="agent_1")  # agent_2's channel goes with agent_2
    assert env.action_space.shape == (11,) and "messages" in env.observation_space.spaces
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0)
    heard = 0
    for _ in range(20):
        obs, _, _, _, info = env.step(env.action_space.sample())
        heard += info["messages_received"]
        assert env.observation_space.contains(obs)
    assert heard > 0  # connected traffic
    env.close()


def test_scenario_comms_section_round_trips_and_bad_fields_name_the_file():
    spec = load_scenario("intersection_v2v")
    assert spec.comms.penetration == 0.5 and spec.comms.latency == 1
    again = read_scenario(scenario_to_dict(spec))
    assert again == spec and again.comms == spec.comms and scenario_to_dict(again) == scenario_to_dict(spec)
    assert read_scenario({**scenario_to_dict(spec), "comms": None}).comms is None
    assert _spec({}).comms.channels == 1  # an empty section: comms on with the defaults
    with pytest.raises(ScenarioError, match=r"test-scenario: comms\.loss: input should be less than 1"):
        _spec({"loss": 1.5})
    with pytest.raises(ScenarioError, match=r"test-scenario: comms\.rang: unknown field; did you mean 'range'\?"):
        _spec({"rang": 10})
    with pytest.raises(ScenarioError, match=r"test-scenario: comms\.agent_channels: unknown agents \['agent_9'\]"):
        _spec({"agent_channels": {"agent_9": 0}})


def test_readme_comms_example_builds_an_env():
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = next(b for b in re.findall(r"```yaml\n(.*?)```", readme, flags=re.DOTALL) if "\ncomms:" in b)
    env = DrivingParallelEnv(_spec(yaml.safe_load(block)["comms"]))
    assert env.action_space("agent_0").shape == (3 + 8,)
    assert env.comms.tuned.tolist() == [0, 1]  # agent_1 listens on channel 1
    obs, _ = env.reset(seed=0)
    assert obs["agent_0"]["messages"].shape == (8, 14)
