import math

import gymnasium
import numpy as np
import pytest

from smarts.dynamics import (
    ActionError,
    ActionSpaceType,
    ReachLimits,
    action_space,
    check_actions,
    lane_command,
)


def test_default_limits_describe_a_passenger_car():
    limits = ReachLimits()
    assert limits.max_speed == pytest.approx(22.22)
    assert limits.min_turning_radius == pytest.approx(5.0)
    assert limits.allow_reverse is False


@pytest.mark.parametrize(
    "field, value",
    [
        ("max_speed", -1.0),
        ("max_accel", 0.0),
        ("max_decel", math.nan),
        ("max_yaw_rate", math.inf),
        ("max_curvature", "0.2"),
        ("max_slip", 2.0),
        ("max_slip", -0.1),
        ("allow_reverse", 1),
        ("max_reverse_speed", -5.0),
    ],
)
def test_invalid_limits_name_the_field(field, value):
    with pytest.raises(ValueError, match=f"ReachLimits.{field}"):
        ReachLimits(**{field: value})


def test_action_space_boxes():
    limits = ReachLimits()
    rel = action_space("relative_target_pose", limits, dt=0.1)
    assert isinstance(rel, gymnasium.spaces.Box) and rel.dtype == np.float32
    np.testing.assert_allclose(rel.high, [2.222, 2.222, 0.12], rtol=1e-6)
    np.testing.assert_allclose(rel.low, -rel.high)

    target = action_space(ActionSpaceType.TARGET_POSE, limits, dt=0.1)
    np.testing.assert_allclose(target.high, [1e5, 1e5, math.pi], rtol=1e-6)

    cont = action_space(ActionSpaceType.CONTINUOUS, limits, dt=0.1)
    np.testing.assert_array_equal(cont.low, [0, 0, -1])
    np.testing.assert_array_equal(cont.high, [1, 1, 1])

    lane = action_space(ActionSpaceType.LANE, limits, dt=0.1)
    assert lane.shape == (2,)
    np.testing.assert_allclose(lane.high, [22.22, 1.0], rtol=1e-6)
    np.testing.assert_array_equal(lane.low, [0, -1])


def test_action_space_rejects_unknown_kind_and_bad_dt():
    with pytest.raises(ValueError, match="unknown action space 'teleport'"):
        action_space("teleport", ReachLimits(), dt=0.1)
    with pytest.raises(ValueError, match="dt must be a positive"):
        action_space("continuous", ReachLimits(), dt=0.0)


def test_check_actions_names_agent_and_component_of_nan():
    actions = np.zeros((4, 3))
    actions[3, 2] = np.nan
    ids = ["agent_0", "agent_1", "agent_2", "agent_3"]
    with pytest.raises(ActionError) as err:
        check_actions("relative_target_pose", actions, ids)
    assert str(err.value) == ("agent_3: relative_target_pose action component dheading is nan; expected finite numbers")
    assert err.value.agent_ids == ["agent_3"]
    assert isinstance(err.value, ValueError)


def test_check_actions_lists_every_bad_agent_once():
    actions = np.zeros((3, 3))
    actions[0, 0] = np.inf
    actions[0, 1] = -np.inf
    actions[2, 2] = np.nan
    with pytest.raises(ActionError) as err:
        check_actions(ActionSpaceType.CONTINUOUS, actions, ["a", "b", "c"])
    assert "a: continuous action component throttle is inf" in str(err.value)
    assert "a: continuous action component brake is -inf" in str(err.value)
    assert "c: continuous action component steering is nan" in str(err.value)
    assert err.value.agent_ids == ["a", "c"]


def test_check_actions_wrong_shapes():
    with pytest.raises(ActionError, match=r"ego: lane action has 3 components; expected 2"):
        check_actions("lane", np.zeros((1, 3)), ["ego"])
    with pytest.raises(ActionError, match=r"shape \(3,\); expected \(1, 3\)"):
        check_actions("target_pose", np.zeros(3), ["ego"])
    with pytest.raises(ActionError, match="not numbers"):
        check_actions("target_pose", [["a", "b", "c"]], ["ego"])
    with pytest.raises(ActionError, match="not numbers"):  # text that looks like numbers is still text
        check_actions("target_pose", [["1", "2", "3"]], ["ego"])
    with pytest.raises(ActionError, match=r"not numbers \(dtype complex128\)"):  # not cut to its real part
        check_actions("target_pose", np.array([[1j, 0, 0]]), ["ego"])
    with pytest.raises(ActionError, match=r"not numbers \(dtype bool\)"):
        check_actions("continuous", np.array([[True, False, False]]), ["ego"])


def test_finite_out_of_range_actions_are_not_errors():
    actions = np.array([[100.0, -50.0, 7.0]], dtype=np.float32)
    checked = check_actions("relative_target_pose", actions, ["ego"])
    assert checked.dtype == np.float64
    np.testing.assert_array_equal(checked, actions)


def test_lane_command_clips_speed_and_rounds_lane_change():
    speed, change = lane_command(np.array([[-3.0, -0.7], [10.0, 0.2], [99.0, 3.0], [5.0, -0.3]]), ReachLimits())
    np.testing.assert_allclose(speed, [0.0, 10.0, 22.22, 5.0])
    np.testing.assert_array_equal(change, [-1, 0, 1, 0])
    assert change.dtype == np.int8
