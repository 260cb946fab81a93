import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role, VehicleTable
from smarts.dynamics import ReachLimits, lane_control_step

DT = 0.1
LIMITS = ReachLimits()
WHEELBASE = 2.7


def test_converges_to_a_straight_lane_and_the_target_speed():
    table = VehicleTable(8)
    rows = np.array(
        [
            table.add("a", owner=0, role=Role.AGENT, x=0.0, y=1.5, heading=0.2, speed=5.0),
            table.add("b", owner=0, role=Role.AGENT, x=0.0, y=-40.0, heading=-0.3, speed=20.0),
        ]
    )
    lane_y = np.array([0.0, -43.5])  # each car follows its own lane centre line y = lane_y
    target_speed = np.array([12.0, 8.0])
    max_accel = max_decel = max_yaw = 0.0
    for _ in range(200):
        lookahead = np.column_stack([table.x[rows] + 8.0, lane_y])
        lane_control_step(table, rows, target_speed, lookahead, DT, LIMITS, WHEELBASE)
        max_accel = max(max_accel, table.accel[rows].max())
        max_decel = min(max_decel, table.accel[rows].min())
        max_yaw = max(max_yaw, np.abs(table.yaw_rate[rows]).max())
    np.testing.assert_allclose(table.y[rows], lane_y, atol=0.05)
    np.testing.assert_allclose(table.heading[rows], 0.0, atol=0.01)
    np.testing.assert_allclose(table.speed[rows], target_speed, atol=0.05)
    assert max_accel <= LIMITS.max_accel + 1e-9
    assert max_decel >= -LIMITS.max_decel - 1e-9
    assert max_yaw <= LIMITS.max_yaw_rate + 1e-9


def test_writes_steering_and_derived_columns():
    table = VehicleTable(4)
    row = table.add("a", owner=0, role=Role.AGENT, x=0.0, y=0.0, heading=0.0, speed=10.0)
    rows = np.array([row])
    lane_control_step(table, rows, np.array([10.0]), np.array([[10.0, 3.0]]), DT, LIMITS, np.array([WHEELBASE]))
    assert table.steering[row] > 0  # the point is on the left
    assert table.yaw_rate[row] > 0 and table.y[row] > 0
    assert table.lat_accel[row] == pytest.approx(table.speed[row] * table.yaw_rate[row])
    # Pure pursuit from the rear axle (half a wheelbase behind the centre): kappa = 2 y / d^2.
    wx, wy = 10.0 + 0.5 * WHEELBASE, 3.0
    assert table.steering[row] == pytest.approx(math.atan(2 * wy / (wx * wx + wy * wy) * WHEELBASE))


def test_sharp_look_ahead_is_capped_by_yaw_rate_and_curvature():
    table = VehicleTable(4)
    rows = np.array(
        [
            table.add("fast", owner=0, role=Role.AGENT, x=0, y=0, heading=0, speed=10.0),
            table.add("slow", owner=0, role=Role.AGENT, x=0, y=50, heading=0, speed=1.0),
        ]
    )
    lane_control_step(
        table,
        rows,
        np.array([10.0, 1.0]),
        np.array([[2.0, -3.0], [2.0, 53.0]]),
        DT,
        LIMITS,
        WHEELBASE,
    )
    # Fast: curvature capped at max_yaw_rate / speed (right turn); slow: at max_curvature.
    np.testing.assert_allclose(
        table.steering[rows],
        [-math.atan(LIMITS.max_yaw_rate / 10.0 * WHEELBASE), math.atan(0.2 * WHEELBASE)],
    )
    assert table.yaw_rate[rows[0]] == pytest.approx(-LIMITS.max_yaw_rate)


def test_target_speed_is_clipped_and_braking_is_limited():
    table = VehicleTable(4)
    rows = np.array([table.add("a", owner=0, role=Role.AGENT, x=0, y=0, heading=0, speed=20.0)])
    lane_control_step(table, rows, np.array([-5.0]), np.array([[30.0, 0.0]]), DT, LIMITS, WHEELBASE)
    assert table.accel[rows[0]] == pytest.approx(-LIMITS.max_decel)
    assert table.jerk[rows[0]] == pytest.approx(-LIMITS.max_decel / DT)
    for _ in range(30):
        lane_control_step(
            table,
            rows,
            np.array([99.0]),
            np.array([[table.x[rows[0]] + 30.0, 0.0]]),
            DT,
            LIMITS,
            WHEELBASE,
        )
    assert table.speed[rows[0]] <= LIMITS.max_speed + 1e-9
    assert table.speed[rows[0]] == pytest.approx(LIMITS.max_speed, abs=0.05)
