"""Shared planner pieces: frames, geometry, paths, the tracker and per-agent state alignment."""

import numpy as np
import pytest

from agents.planners.agent_state import AgentState, align
from agents.planners.frames import Odometry, chain, compose, relative, unchain, wrap
from agents.planners.geometry import (
    bezier_length,
    bezier_points,
    bezier_tangents,
    collision_forecast,
    cubic_coefficients,
    polyval,
    quintic_coefficients,
)  # fmt: skip
from agents.planners.paths import Reference, arc_length, extend, from_ego, project
from agents.planners.tracker import NeighbourTracker


def test_chain_round_trip_and_compose_inverse():
    rng = np.random.default_rng(0)
    poses = np.cumsum(rng.normal(0, [1.0, 0.3, 0.05], (30, 3)), axis=0)
    poses[:, 2] = wrap(poses[:, 2])
    steps = chain(poses)
    np.testing.assert_allclose(unchain(steps), poses, atol=1e-9)
    a, b = np.array([1.0, 2.0, 0.3]), np.array([4.0, -1.0, -2.0])
    np.testing.assert_allclose(compose(a, relative(a, b)), b, atol=1e-12)


def test_odometry_dead_reckons_a_quarter_circle():
    odo = Odometry()
    for _ in range(10):
        odo.advance(np.array([1.0, 0.0, np.pi / 20]))
    assert odo.pose[2] == pytest.approx(np.pi / 2)
    # a point ahead of the ego now lies to the left of where it started
    ahead = odo.to_world(np.array([[1.0, 0.0]]))[0]
    assert ahead[1] > odo.pose[1] and odo.to_ego(ahead[None])[0] == pytest.approx([1.0, 0.0])


def test_collision_forecast_corner_in_box_and_forecast_steps():
    def hit(x, y, heading=0.0, speed=0.0, ego_speed=0.0, steps=5, l_front=5.0):
        return bool(
            collision_forecast(
                ego_speed,
                4.6,
                1.9,
                np.array([[x, y]]),
                np.array([heading]),
                np.array([speed]),
                np.array([4.6]),
                np.array([1.9]),
                l_front,
                1.25,
                1.25,
                steps,
            )[0]
        )

    assert hit(9.0, 0.0)  # rear bumper 6.7 m ahead: inside 2.3 + 5 m
    assert not hit(10.0, 0.0)  # rear bumper at 7.7 m: beyond the box
    assert hit(10.0, 0.0, ego_speed=10.0)  # the ego closes 5 m in 0.5 s
    assert not hit(10.0, 0.0, ego_speed=10.0, steps=0)
    assert not hit(0.0, 4.3)  # corners 3.35 m left: box reaches 0.95 + 1.25 = 2.2 m
    assert hit(0.0, 3.0)  # corners at 2.05 m: inside
    assert hit(0.0, -3.0)  # right side, same widths


def test_bezier_points_tangents_and_length():
    rng = np.random.default_rng(1)
    control = rng.normal(size=(6, 2))
    t = np.linspace(0, 1, 11)
    pts = bezier_points(control, t)
    np.testing.assert_allclose(pts[0], control[0])
    np.testing.assert_allclose(pts[-1], control[-1])
    np.testing.assert_allclose(bezier_tangents(control, np.array([0.0]))[0], 5 * (control[1] - control[0]))
    np.testing.assert_allclose(bezier_tangents(control, np.array([1.0]))[0], 5 * (control[-1] - control[-2]))
    # tangent = the derivative: compare with central differences
    h = 1e-6
    fd = (bezier_points(control, t[1:-1] + h) - bezier_points(control, t[1:-1] - h)) / (2 * h)
    np.testing.assert_allclose(bezier_tangents(control, t[1:-1]), fd, rtol=1e-5, atol=1e-6)
    dense = bezier_points(control, np.linspace(0, 1, 20001))
    assert bezier_length(control) == pytest.approx(arc_length(dense)[-1], rel=1e-3)
    line = np.stack([np.arange(8.0), np.zeros(8)], axis=1)  # evenly spaced collinear: uniform speed
    np.testing.assert_allclose(bezier_points(line, np.array([1 / 7, 0.5]))[:, 0], [1.0, 3.5])


def test_polynomial_boundary_conditions():
    c = cubic_coefficients(10.0, 1.5, 4.0, 0.0, 2.0)
    assert polyval(c, 0.0) == pytest.approx(10.0) and polyval(c, 0.0, 1) == pytest.approx(1.5)
    assert polyval(c, 2.0) == pytest.approx(4.0) and polyval(c, 2.0, 1) == pytest.approx(0.0, abs=1e-12)
    q = quintic_coefficients(3.5, -0.4, 0.2, 0.0, 0.0, 0.0, 2.3)
    for k, want in enumerate([3.5, -0.4, 0.2]):
        assert polyval(q, 0.0, k) == pytest.approx(want)
        assert polyval(q, 2.3, k) == pytest.approx(0.0, abs=1e-9)


def test_path_projection_extension_and_reference():
    path = np.stack([np.arange(0.0, 10.0), np.zeros(10), np.zeros(10)], axis=1)
    s, d = project(path[:, :2], np.array([[3.5, 1.0], [2.0, -0.5], [-1.0, 0.2], [12.0, 0.0]]))
    np.testing.assert_allclose(s, [3.5, 2.0, -1.0, 12.0])
    np.testing.assert_allclose(d, [1.0, -0.5, 0.2, 0.0], atol=1e-12)
    longer = extend(path, 15)
    assert len(longer) == 15 and longer[-1, 0] == pytest.approx(14.0)
    arc = np.stack([10 * np.sin(np.linspace(0, 1, 30)), 10 - 10 * np.cos(np.linspace(0, 1, 30))], axis=1)
    ref = Reference(np.column_stack([arc, np.zeros(30)]))
    assert ref.length == pytest.approx(10.0, rel=1e-3)  # chord sum of a 10 m arc
    xy, yaw, valid = ref.frenet_to_xy(np.array([5.0]), np.array([1.0]))
    assert valid[0] and yaw[0] == pytest.approx(0.5, abs=5e-3)
    assert np.hypot(xy[0, 0], xy[0, 1] - 10.0) == pytest.approx(9.0, abs=1e-2)  # 1 m towards the centre
    ahead = from_ego(path - np.array([0.3, 0.0, 0.0]))  # the ego 0.3 m past the grid point
    assert ahead[0, 0] == pytest.approx(0.0, abs=1e-9) and ahead[1, 0] == pytest.approx(1.0)


def test_tracker_keeps_ids_through_occlusion():
    tracker = NeighbourTracker()

    def obs(xs, present):
        nb = np.zeros((3, 9))
        nb[:, 0], nb[:, 1], nb[:, 2] = xs, [0.0, 3.2, -3.2], 1.0
        nb[:, 4] = [-2.0, 1.0, 0.0]  # relative vx with the ego at 10 m/s: 8, 11, 10 m/s
        nb[:, 6:8] = [4.6, 1.9]
        return nb, np.array(present, dtype=float)

    odo = Odometry()
    first = None
    xs = np.array([20.0, 5.0, -10.0])
    for k in range(15):
        present = [1, 0 if 4 <= k < 9 else 1, 1]  # the second car is hidden for 5 steps
        nb, mask = obs(xs, present)
        ids = tracker.update(odo.pose, 10.0, nb, mask)
        if first is None:
            first = ids.copy()
        assert ids[0] == first[0] and ids[2] == first[2]
        if present[1]:
            assert ids[1] == first[1]
        else:
            assert ids[1] == -1
        odo.advance(np.array([1.0, 0.0, 0.0]))
        xs = xs + np.array([-0.2, 0.1, 0.0])  # relative motion in the ego frame
    hist = tracker.history(int(first[1]))
    assert np.count_nonzero(hist[:, 3]) == 6  # seen again for the last 6 frames, gap before
    assert len(set(first.tolist())) == 3


def test_align_drops_the_agent_that_left():
    states = []
    for speed, route in [(10.0, 100.0), (5.0, 50.0), (12.0, 200.0)]:
        s = AgentState()
        s.observe(np.r_[speed, np.zeros(11)])
        s.acted(np.array([speed * 0.1, 0.0, 0.0]), np.array([0, 0, route, 1.0]), 0.1)
        states.append(s)
    ego = np.zeros((2, 12))
    ego[:, 0] = [10.0, 12.0]
    goal = np.array([[0, 0, 99.0, 1.0], [0, 0, 198.8, 1.0]])
    picked = align(states, {"ego": ego, "goal": goal})
    assert picked[0] is states[0] and picked[1] is states[2]
    ego[1, 0] = 3.0  # not anyone's next step: starts afresh
    assert align(states, {"ego": ego[:1].repeat(3, 0), "goal": goal[:1].repeat(3, 0)})[1] is None


def test_align_keeps_an_agent_braking_for_a_stop():
    # a zero step at 12 m/s is a brake (at most 9 m/s^2): the next observation at 11.1 m/s is
    # this agent's, not a new one (its memory, e.g. TF's hold or VCR's scores, must survive)
    s = AgentState()
    s.observe(np.r_[12.0, np.zeros(11)])
    s.acted(np.zeros(3), np.array([0, 0, 100.0, 1.0]), 0.1)
    ego = np.r_[11.1, np.zeros(11)][None]
    assert align([s], {"ego": ego, "goal": np.array([[0, 0, 98.8, 1.0]])})[0] is s
