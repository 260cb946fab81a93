import math

import numpy as np
import pytest

from smarts.dynamics import (
    bicycle_step,
    curvature_for_steering,
    steering_for_curvature,
    wheelbase_for_length,
)

L = 2.7


def run(steps, dt, x=0.0, y=0.0, h=0.0, v=10.0, accel=0.0, steer=0.0, ref_ahead=0.0):
    state = tuple(np.array([val], dtype=float) for val in (x, y, h, v))
    trace = [state]
    for _ in range(steps):
        state = bicycle_step(*state, accel, steer, L, dt, ref_ahead)
        trace.append(state)
    return trace


def circumradius(p1, p2, p3):
    a, b, c = np.linalg.norm(p2 - p3), np.linalg.norm(p1 - p3), np.linalg.norm(p1 - p2)
    area2 = abs((p2[0] - p1[0]) * (p3[1] - p1[1]) - (p3[0] - p1[0]) * (p2[1] - p1[1]))
    return a * b * c / (2.0 * area2)


def test_straight_line_at_constant_speed():
    x, y, h, v = run(10, 0.1, h=0.3, v=10.0)[-1]
    assert x[0] == pytest.approx(10.0 * math.cos(0.3))
    assert y[0] == pytest.approx(10.0 * math.sin(0.3))
    assert h[0] == pytest.approx(0.3) and v[0] == pytest.approx(10.0)


def test_constant_steering_drives_a_circle_of_radius_wheelbase_over_tan_steer():
    steer = 0.3
    radius = L / math.tan(steer)
    dt, v = 0.1, 8.0
    trace = run(400, dt, v=v, steer=steer)
    pts = [np.array([s[0][0], s[1][0]]) for s in trace]
    assert circumradius(pts[0], pts[37], pts[101]) == pytest.approx(radius, rel=1e-9)
    # Left turn: the centre is on the left of the start pose and the heading grows.
    assert trace[1][2][0] > 0
    loop_steps = 2 * math.pi * radius / v / dt
    full = run(1, loop_steps * dt, v=v, steer=steer)[-1]  # exact: one step is the whole loop
    assert (full[0][0], full[1][0]) == pytest.approx((0.0, 0.0), abs=1e-9)


def test_reference_point_ahead_of_rear_axle_circles_on_the_wider_radius():
    steer, ahead = -0.25, 0.5 * L
    trace = run(60, 0.1, v=6.0, steer=steer, ref_ahead=ahead)
    pts = [np.array([s[0][0], s[1][0]]) for s in trace]
    expected = math.hypot(L / math.tan(abs(steer)), ahead)
    assert circumradius(pts[0], pts[20], pts[55]) == pytest.approx(expected, rel=1e-9)
    assert trace[1][2][0] < 0  # right turn


def test_exact_integration_is_step_size_independent():
    coarse = run(1, 2.0, v=5.0, accel=1.5, steer=0.2)[-1]
    fine = run(200, 0.01, v=5.0, accel=1.5, steer=0.2)[-1]
    for a, b in zip(coarse, fine):
        assert a[0] == pytest.approx(b[0], abs=1e-9)


def test_braking_stops_at_zero_speed_without_reversing():
    x, y, h, v = run(1, 1.0, v=2.0, accel=-4.0)[-1]
    assert v[0] == 0.0
    assert x[0] == pytest.approx(0.5)  # v^2 / (2 a): stopped after 0.5 s
    x2, _, _, v2 = bicycle_step(x, y, h, v, -4.0, 0.3, L, 1.0)
    assert v2[0] == 0.0 and x2[0] == x[0]


def test_vectorised_with_per_vehicle_wheelbase():
    n = 3
    x, y, h, v = bicycle_step(
        np.zeros(n),
        np.zeros(n),
        np.zeros(n),
        np.full(n, 5.0),
        np.zeros(n),
        np.full(n, 0.2),
        np.array([2.0, 3.0, 6.0]),
        1.0,
    )
    np.testing.assert_allclose(h, 5.0 * math.tan(0.2) / np.array([2.0, 3.0, 6.0]))


def test_steering_curvature_helpers_are_inverse():
    k = np.array([-0.15, 0.0, 0.1])
    np.testing.assert_allclose(curvature_for_steering(steering_for_curvature(k, L), L), k)
    assert float(wheelbase_for_length(4.5)) == pytest.approx(2.7)
