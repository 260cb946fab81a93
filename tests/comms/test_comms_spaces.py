import numpy as np
import pytest

from smarts.comms import (
    MESSAGE_FEATURES,
    CommsConfig,
    V2VNetwork,
    message_action_components,
    message_action_space,
    received_observation_space,
    received_to_observation,
    split_message_action,
)
from smarts.dynamics.action_spaces import ActionError
from tests.comms.support import rows_of, table_with


def test_action_space_is_payload_then_optional_channel():
    space = message_action_space(CommsConfig(message_size=3, payload_bound=2.0))
    assert space.shape == (3,) and space.dtype == np.float32
    assert space.low.tolist() == [-2.0] * 3 and space.high.tolist() == [2.0] * 3
    config = CommsConfig(message_size=2, channels=4, channel_action=True)
    space = message_action_space(config)
    assert space.low.tolist() == [-1, -1, 0] and space.high.tolist() == [1, 1, 3]
    assert message_action_components(config) == ("payload_0", "payload_1", "channel")


def test_split_clips_payload_and_rounds_the_channel():
    config = CommsConfig(message_size=2, channels=3, channel_action=True)
    payloads, channels = split_message_action(config, np.array([[0.5, 4.0, 1.4], [-3.0, 0.0, 9.0]]), ["a", "b"])
    assert payloads.dtype == np.float32 and payloads.tolist() == [[0.5, 1.0], [-1.0, 0.0]]
    assert channels.tolist() == [1, 2]

    fixed = CommsConfig(message_size=1, channels=2, agent_channels={"b": 1})
    _, channels = split_message_action(fixed, np.zeros((2, 1)), ["a", "b"], fixed.fixed_channels(["a", "b"]))
    assert channels.tolist() == [0, 1]


def test_split_names_agents_with_bad_message_actions():
    config = CommsConfig(message_size=2)
    with pytest.raises(ActionError, match=r"b: message action component payload_1 is nan") as err:
        split_message_action(config, np.array([[0.0, 0.0], [0.0, np.nan]]), ["a", "b"])
    assert err.value.agent_ids == ["b"]
    with pytest.raises(ActionError, match=r"shape \(2, 3\); expected \(2, 2\)"):
        split_message_action(config, np.zeros((2, 3)), ["a", "b"])


def test_observation_holds_the_received_messages_within_its_space():
    config = CommsConfig(message_size=3, max_messages=4, penetration=1.0, latency=1, range=50.0)
    poses = {"r": (0.0, 0.0, 0.0), "s": (10.0, 0.0, 0.0), "t": (-5.0, 0.0, 0.0)}
    table, rows = table_with(poses, traffic=("t",))
    net = V2VNetwork(config, table.capacity, seed=1)
    for step in range(2):
        net.send(step, table, rows_of(rows, "s"), 0, np.array([[0.1, 0.2, 0.3]]))
        net.broadcast_traffic(step, table)
        received = net.deliver(step, table, rows_of(rows, "r", "s"))
    obs = received_to_observation(received)
    spaces = received_observation_space(config)
    assert obs["messages"].shape == (2, 4, len(MESSAGE_FEATURES) + 3)
    assert obs["messages"].dtype == np.float32 and obs["message_mask"].dtype == np.float32
    for i in range(2):
        assert all(spaces[k].contains(obs[k][i]) for k in spaces)
    first, second = obs["messages"][0, 0], obs["messages"][0, 1]  # traffic at 5 m, agent at 10 m
    np.testing.assert_allclose(first[:6], [0, 1, -5, 0, 0, 1])
    np.testing.assert_allclose(first[6:], [-5, 0, 0])  # traffic payload: its x, y, heading
    np.testing.assert_allclose(second, [1, 0, 10, 0, 0, 1, 0.1, 0.2, 0.3], rtol=1e-6)
    assert obs["message_mask"][0].tolist() == [1, 1, 0, 0]
    assert (obs["messages"][0, 2:] == 0).all()
