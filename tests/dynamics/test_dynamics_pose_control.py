import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role, VehicleTable
from smarts.dynamics import (
    ActionError,
    ReachLimits,
    apply_relative_pose,
    apply_target_pose,
    limit_relative_pose,
    wrap_angle,
)

DT = 0.1
LIMITS = ReachLimits()


def limit(dx, dy, dh, speed, limits=LIMITS):
    out = limit_relative_pose(np.array([[dx, dy, dh]], dtype=float), np.array([speed]), DT, limits)
    return tuple(float(a[0]) for a in out)


def make_table(poses):
    table = VehicleTable(64)
    rows = [
        table.add(f"car{i}", owner=0, role=Role.AGENT, x=x, y=y, heading=h, speed=v)
        for i, (x, y, h, v) in enumerate(poses)
    ]
    return table, np.array(rows)


def test_wrap_angle_range_and_identity_inside():
    a = np.array([math.pi, -math.pi, 0.3, -0.3, 3 * math.pi, -2.5 * math.pi, 7.0])
    w = wrap_angle(a)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert w[0] == math.pi and w[1] == math.pi
    assert w[2] == 0.3  # bit-identical inside the range


def test_request_within_limits_passes_unchanged():
    assert limit(1.0, 0.0, 0.0, 10.0) == (1.0, 0.0, 0.0, 10.0)
    dx, dy, dh, v = limit(1.0, 0.02, 0.04, 10.0)  # a gentle left curve along its chord
    assert (dx, dy, dh) == pytest.approx((1.0, 0.02, 0.04), abs=1e-12)
    assert v == pytest.approx(math.hypot(1.0, 0.02) / DT)


def test_too_long_displacement_is_scaled_to_the_reachable_one():
    dx, dy, dh, v = limit(5.0, 0.0, 0.0, 10.0)
    assert v == pytest.approx(10.0 + LIMITS.max_accel * DT)
    assert (dx, dy) == pytest.approx((v * DT, 0.0))
    # The direction of an oblique request survives when it lies inside the slip window.
    dx, dy, dh, v = limit(3.0, 0.15, 0.1, 10.0)
    assert math.hypot(dx, dy) == pytest.approx(1.04)
    assert math.atan2(dy, dx) == pytest.approx(math.atan2(0.15, 3.0))


def test_speed_is_capped_and_a_car_above_it_brakes_at_most_max_decel():
    dx, _, _, v = limit(3.0, 0.0, 0.0, 22.0)
    assert v == pytest.approx(LIMITS.max_speed)
    _, _, _, v = limit(3.0, 0.0, 0.0, 30.0)
    assert v == pytest.approx(30.0 - LIMITS.max_decel * DT)


def test_acceleration_and_deceleration_limits():
    dx, dy, dh, v = limit(2.0, 0.0, 0.0, 0.0)  # from rest
    assert v == pytest.approx(LIMITS.max_accel * DT)
    assert dx == pytest.approx(v * DT)
    _, _, _, v = limit(0.0, 0.0, 0.0, 10.0)  # asks to stand still at once
    assert v == pytest.approx(10.0 - LIMITS.max_decel * DT)
    _, _, _, v = limit(0.05, 0.0, 0.0, 0.8)  # a stop that is reachable this step
    assert v == pytest.approx(0.5)


def test_heading_change_limited_by_yaw_rate_and_curvature():
    assert limit(1.0, 0.0, 0.5, 10.0)[2] == pytest.approx(LIMITS.max_yaw_rate * DT)
    assert limit(1.0, 0.0, -0.5, 10.0)[2] == pytest.approx(-LIMITS.max_yaw_rate * DT)
    # Slow: the turning radius binds, |dh| <= max_curvature * distance.
    dx, dy, dh, _ = limit(0.1, 0.0, 0.5, 1.0)
    assert dh == pytest.approx(LIMITS.max_curvature * math.hypot(dx, dy))
    assert limit(0.0, 0.0, 0.5, 0.0)[2] == 0.0  # no turning on the spot


def test_displacement_follows_the_chord_within_max_slip():
    dx, dy, dh, _ = limit(0.0, 1.0, 0.0, 10.0)  # a sideways jump
    assert math.atan2(dy, dx) == pytest.approx(LIMITS.max_slip)
    dx, dy, dh, _ = limit(1.0, -0.5, -0.1, 10.0)
    assert math.atan2(dy, dx) == pytest.approx(-0.05 - LIMITS.max_slip)


def test_backward_request_is_a_stop_request_without_reverse():
    dx, dy, dh, v = limit(-1.0, 0.0, 0.0, 10.0)
    assert v == pytest.approx(10.0 - LIMITS.max_decel * DT)
    assert dx == pytest.approx(v * DT) and dy == pytest.approx(0.0)
    assert limit(-1.0, 0.0, 0.2, 0.0) == (0.0, 0.0, 0.0, 0.0)


def test_reverse_when_allowed():
    limits = ReachLimits(allow_reverse=True, max_reverse_speed=3.0)
    dx, dy, dh, v = limit(-1.0, 0.0, 0.0, 0.0, limits)
    assert v == pytest.approx(-limits.max_accel * DT)
    assert dx == pytest.approx(v * DT) and dy == pytest.approx(0.0)
    _, _, _, v = limit(-1.0, 0.0, 0.0, -2.9, limits)
    assert v == pytest.approx(-3.0)  # capped at max_reverse_speed
    _, _, _, v = limit(-1.0, 0.0, 0.0, 5.0, limits)
    assert v == pytest.approx(5.0 - limits.max_decel * DT)  # still braking forward
    # Backing along a curve: the displacement lies along the rear chord.
    dx, dy, dh, v = limit(-0.2, -0.01, 0.02, -2.0, limits)
    assert (dx, dy, dh) == pytest.approx((-0.2, -0.01, 0.02), abs=1e-12)
    assert v == pytest.approx(-math.hypot(0.2, 0.01) / DT)


def test_vectorised_rows_match_single_rows():
    rng = np.random.default_rng(3)
    n = 50
    req = np.column_stack([rng.uniform(-1, 4, n), rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, n)])
    speed = rng.uniform(0, 25, n)
    batch = limit_relative_pose(req, speed, DT, LIMITS)
    for i in range(n):
        single = limit(*req[i], speed[i])
        assert single == pytest.approx(tuple(a[i] for a in batch), abs=1e-15)
    v = batch[3]
    assert np.all(v >= 0)
    assert np.all(v >= speed - LIMITS.max_decel * DT - 1e-9)
    assert np.all(v <= speed + LIMITS.max_accel * DT + 1e-9)
    assert np.all(v <= np.maximum(LIMITS.max_speed, speed - LIMITS.max_decel * DT) + 1e-9)


def test_apply_relative_pose_writes_pose_and_derived_columns():
    table, rows = make_table([(10.0, 5.0, math.pi / 2, 10.0), (0.0, 0.0, 0.0, 5.0)])
    table.accel[rows] = [1.0, 0.0]
    actions = np.array([[1.02, 0.0, 0.05], [0.5, 0.0, 0.0]])
    apply_relative_pose(table, rows, actions, DT, LIMITS)
    # Car 0 faces +y: forward displacement 1.02 becomes +y in the world, its direction already
    # within max_slip of the chord.
    assert table.x[rows[0]] == pytest.approx(10.0, abs=1e-12)
    assert table.y[rows[0]] == pytest.approx(6.02)
    assert table.heading[rows[0]] == pytest.approx(math.pi / 2 + 0.05)
    np.testing.assert_allclose(table.speed[rows], [10.2, 5.0])
    np.testing.assert_allclose(table.accel[rows], [2.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(table.jerk[rows], [10.0, 0.0], atol=1e-8)
    np.testing.assert_allclose(table.yaw_rate[rows], [0.5, 0.0])
    np.testing.assert_allclose(table.lat_accel[rows], [10.2 * 0.5, 0.0])
    # A second, steady step: acceleration returns to zero and jerk records the drop.
    apply_relative_pose(table, rows, np.array([[1.02, 0.0, 0.0], [0.5, 0.0, 0.0]]), DT, LIMITS)
    np.testing.assert_allclose(table.accel[rows], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(table.jerk[rows], [-20.0, 0.0], atol=1e-7)


def test_heading_written_is_wrapped():
    table, rows = make_table([(0.0, 0.0, math.pi - 0.01, 10.0)])
    apply_relative_pose(table, rows, np.array([[1.0, 0.0, 0.1]]), DT, LIMITS)
    assert table.heading[rows[0]] == pytest.approx(-math.pi + 0.09)


def test_bad_action_raises_naming_the_vehicle_and_leaves_table_untouched():
    table, rows = make_table([(0.0, 0.0, 0.0, 10.0), (5.0, 0.0, 0.0, 10.0)])
    before = table.x.copy(), table.speed.copy()
    actions = np.array([[1.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    with pytest.raises(ActionError, match="car1: relative_target_pose action component dx is nan"):
        apply_relative_pose(table, rows, actions, DT, LIMITS)
    with pytest.raises(ActionError, match="car0: target_pose action component heading is inf"):
        apply_target_pose(table, rows, np.array([[1.0, 0.0, np.inf], [5, 0, 0]]), DT, LIMITS)
    with pytest.raises(ActionError, match="expected 3"):
        apply_relative_pose(table, rows, np.zeros((2, 2)), DT, LIMITS)
    np.testing.assert_array_equal(table.x, before[0])
    np.testing.assert_array_equal(table.speed, before[1])


def test_target_pose_equals_relative_target_pose():
    rng = np.random.default_rng(7)
    n = 20
    poses = [
        (rng.uniform(-100, 100), rng.uniform(-100, 100), rng.uniform(-math.pi, math.pi), s)
        for s in rng.uniform(0, 20, n)
    ]
    poses[0] = (1.0, 2.0, math.pi - 0.02, 8.0)  # the target heading wraps across +-pi
    rel = np.column_stack([rng.uniform(-0.5, 3, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)])
    rel[0] = [0.8, 0.0, 0.06]
    table_rel, rows = make_table(poses)
    table_abs, _ = make_table(poses)
    h = table_abs.heading[rows]
    world = np.column_stack(
        [
            table_abs.x[rows] + np.cos(h) * rel[:, 0] - np.sin(h) * rel[:, 1],
            table_abs.y[rows] + np.sin(h) * rel[:, 0] + np.cos(h) * rel[:, 1],
            wrap_angle(h + rel[:, 2]),
        ]
    )
    assert world[0, 2] < 0  # wrapped
    apply_relative_pose(table_rel, rows, rel, DT, LIMITS)
    apply_target_pose(table_abs, rows, world, DT, LIMITS)
    for col in ("x", "y", "heading", "speed", "accel", "jerk", "yaw_rate", "lat_accel"):
        np.testing.assert_allclose(getattr(table_abs, col)[rows], getattr(table_rel, col)[rows], atol=1e-9, err_msg=col)
