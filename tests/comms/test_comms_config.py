import pytest

from smarts.comms import CommsConfig
from smarts.core.errors import ScenarioError


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("range", -5.0, r"comms\.range: input should be greater than 0"),
        ("range", float("inf"), r"comms\.range: input should be a finite number"),
        ("loss", 1.0, r"comms\.loss: input should be less than 1"),
        ("penetration", 1.5, r"comms\.penetration: input should be less than or equal to 1"),
        ("latency", -1, r"comms\.latency: input should be greater than or equal to 0"),
        ("latency", 1.5, r"comms\.latency: input should be a valid integer"),
        ("channels", 0, r"comms\.channels"),
        ("max_messages", True, r"comms\.max_messages: input should be a valid integer, got True"),
        ("message_size", 0, r"comms\.message_size"),
        ("bandwidth", 0, r"comms\.bandwidth: input should be greater than or equal to 1"),
        ("traffic_channel", 1, r"comms\.traffic_channel: .* \[0, 0\], got 1"),
        ("payload_bound", 0.0, r"comms\.payload_bound"),
        ("channel_action", "yes", r"comms\.channel_action: input should be a valid boolean"),
    ],
)
def test_bad_values_name_the_field(field, value, message):
    with pytest.raises(ScenarioError, match=message):
        CommsConfig(**{field: value})


def test_byte_budget_must_hold_one_message():
    with pytest.raises(ScenarioError, match=r"comms\.bandwidth_bytes: 20 bytes cannot hold one message of 48"):
        CommsConfig(message_size=8, bandwidth_bytes=20)


def test_agent_channels_are_checked_against_channels_and_agents():
    with pytest.raises(ScenarioError, match=r"comms\.agent_channels\.agent_1: expected a channel in \[0, 1\]"):
        CommsConfig(channels=2, agent_channels={"agent_1": 2})
    config = CommsConfig(channels=2, agent_channels={"agent_1": 1})
    assert config.fixed_channels(["agent_0", "agent_1"]).tolist() == [0, 1]
    with pytest.raises(ScenarioError, match=r"comms\.agent_channels: unknown agents \['agent_1'\]"):
        config.check_agents(["agent_0"])


def test_receive_limit_is_the_tightest_limit():
    assert CommsConfig(max_messages=8).receive_limit == 8
    assert CommsConfig(max_messages=8, bandwidth=3).receive_limit == 3
    # 16 header + 4 x 4 payload = 32 bytes per message: 100 bytes hold 3 of them.
    config = CommsConfig(max_messages=8, message_size=4, bandwidth_bytes=100)
    assert config.message_bytes == 32 and config.receive_limit == 3


def test_from_dict_reads_values_and_rejects_unknown_keys():
    config = CommsConfig.from_dict({"range": 50, "latency": 2, "loss": 0.1, "penetration": 0.5})
    assert (config.range, config.latency, config.loss, config.penetration) == (50, 2, 0.1, 0.5)
    assert CommsConfig.from_dict(None) == CommsConfig()
    with pytest.raises(ScenarioError, match=r"^comms\.rang: unknown field; did you mean 'range'\?"):
        CommsConfig.from_dict({"rang": 50})
    with pytest.raises(ScenarioError, match=r"scenario\.comms\.loss"):
        CommsConfig.from_dict({"loss": -0.1}, where="scenario.comms")
    with pytest.raises(ScenarioError, match=r"comms: expected a mapping"):
        CommsConfig.from_dict([1, 2])


def test_every_problem_is_reported_at_once():
    with pytest.raises(ScenarioError) as err:
        CommsConfig.from_dict({"loss": 1.5, "channels": True, "latncy": 1}, where="f.yaml: comms")
    lines = str(err.value).splitlines()
    assert lines == [
        "f.yaml: comms.channels: input should be a valid integer, got True",
        "f.yaml: comms.loss: input should be less than 1, got 1.5",
        "f.yaml: comms.latncy: unknown field; did you mean 'latency'? (known: agent_channels, bandwidth, "
        "bandwidth_bytes, channel_action, channels, latency, loss, max_messages, message_size, payload_bound, "
        "penetration, range, traffic_channel)",
    ]
