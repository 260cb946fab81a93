"""Rules of the three planners on hand-built observations."""

import numpy as np
import pytest

from agents.planners import aid, vcr
from agents.planners.tf import HOLD_STEPS, IGNORE_STEPS, TFPlanner, stop_move_features


def observation(neighbours=(), speed=10.0, lanes=(0.0,), count=51, goal=(0.0, 0.0, 0.0, 0.0)):
    """One agent's observation on straight lanes at the given lateral offsets (path 0 first)."""
    wp = np.zeros((1, 3, count, 3), dtype=np.float32)
    mask = np.zeros((1, 3, count), dtype=np.float32)
    for p, y in enumerate(lanes):
        wp[0, p, :, 0] = np.arange(count)
        wp[0, p, :, 1] = y
        mask[0, p] = 1.0
    nb = np.zeros((1, 10, 9), dtype=np.float32)
    nmask = np.zeros((1, 10), dtype=np.float32)
    for i, (x, y, v) in enumerate(neighbours):  # v: the neighbour's speed along +x
        nb[0, i] = [x, y, 1.0, 0.0, v - speed, 0.0, 4.6, 1.9, 0.0]
        nmask[0, i] = 1.0
    ego = np.zeros((1, 12), dtype=np.float32)
    ego[0, [0, 8, 9, 10, 11]] = [speed, 3.2, 13.89, 4.6, 1.9]
    return {"ego": ego, "neighbours": nb, "neighbour_mask": nmask, "waypoints": wp, "waypoint_mask": mask,
            "goal": np.array([goal], dtype=np.float32)}  # fmt: skip


# ----------------------------------------------------------------------------- AID
def test_aid_profiles_meet_their_boundary_conditions():
    v = aid.longitudinal_profile(10.0, 0.0, -2.0)  # v_T = 4, T = 3 s
    assert v[0] == pytest.approx(10.0) and v[-1] == pytest.approx(4.0, abs=0.1)
    assert np.all(np.diff(v) <= 1e-9)
    assert np.all(aid.longitudinal_profile(15.0, 0.0, 5.0) <= aid.MAX_SPEED)
    d = aid.lateral_profile(3.2, 0.0)
    assert abs(d[0]) < 3.2 and d[-1] == 0.0 and np.all(np.diff(d) <= 1e-9)
    assert d[int(3.2 / 1.5 / 0.1)] == pytest.approx(0.0, abs=1e-6)  # back on the path after |d0| / 1.5 s


def test_aid_candidates_costs_and_emergency():
    planner = aid.AIDPlanner()
    obs = observation(lanes=(0.0, 3.2, -3.2))
    planner.act(obs)
    assert len(planner.last_candidates) == 33  # 3 paths x 11 accelerations
    free = {(c.path, c.accel): c.terms for c in planner.last_candidates}
    assert all(t[6] == 0 and t[4] < 1e-6 for t in free.values())  # nobody near: no collision, prox ~ 0
    # a stopped car 8 m ahead in every lane: every candidate collides -> the emergency brake
    planner = aid.AIDPlanner()
    obs = observation(neighbours=[(8.0, 0.0, 0.0), (8.0, 3.2, 0.0), (8.0, -3.2, 0.0)], lanes=(0.0, 3.2, -3.2))
    action = planner.act(obs)[0]
    assert planner._states[0].emergency
    assert action[0] == pytest.approx((10.0 - aid.EMERGENCY_DECEL * 0.1) * 0.1, abs=1e-3)
    coll = np.array([c.terms[6] for c in planner.last_candidates])
    ttc = np.array([c.terms[5] for c in planner.last_candidates])
    assert coll.all() and (ttc > 0).all() and (ttc < 1).all()


def test_aid_prefers_the_free_lane_around_a_stopped_car():
    planner = aid.AIDPlanner()
    planner.act(observation(neighbours=[(15.0, 0.0, 0.0)], lanes=(0.0, 3.2)))
    best = planner.last_candidates[int(np.argmin(planner.last_costs))]
    assert best.path == 1 and best.terms[6] == 0


def test_aid_kinematic_costs_are_zero_at_constant_speed():
    t = np.arange(30) * 0.1
    xy = np.stack([10 * t, np.zeros(30)], axis=1)
    assert aid.kinematic_costs(xy, np.zeros(30)) == pytest.approx((0.0, 0.0), abs=1e-9)
    xy[:, 0] = 10 * t + 0.5 * 2.0 * t**2  # constant acceleration: no jerk
    assert aid.kinematic_costs(xy, np.zeros(30))[0] == pytest.approx(0.0, abs=1e-6)


# ----------------------------------------------------------------------------- VCR
def test_vcr_speed_map_and_obstacle_cones():
    assert vcr.speed_factor(0.0) == pytest.approx(0.9975, abs=1e-4)
    assert vcr.speed_factor(0.3) == pytest.approx(0.5)
    assert vcr.speed_factor(0.5) == pytest.approx(0.018, abs=1e-3)
    obs = observation(neighbours=[(8.0, 1.0, 5.0), (-4.0, 0.0, 10.0), (0.0, 8.0, 10.0), (20.0, 0.0, 5.0)])
    row = {k: v[0] for k, v in obs.items()}
    front, rear = vcr.obstacles(row)
    assert front.tolist() == [0] and rear.tolist() == [1]  # beside (90 deg) and beyond 12 m: neither


def test_vcr_cruise_tailgated_and_slowdown_factors():
    planner = vcr.VCRPlanner()
    planner.act(observation())
    assert planner._states[0].factor == pytest.approx(1.1)
    planner = vcr.VCRPlanner()
    step = planner.act(observation(neighbours=[(-4.5, 0.0, 10.0)]))[0]
    assert planner._states[0].factor == pytest.approx(2.5) and step[0] == pytest.approx(2.5, abs=0.05)
    planner = vcr.VCRPlanner()
    planner.act(observation(neighbours=[(9.0, 0.0, 2.0)]))
    assert planner._states[0].factor < 0.05


def test_vcr_switches_path_only_after_ten_agreeing_steps():
    planner = vcr.VCRPlanner()
    state = planner.new_state()
    obs = observation(lanes=(3.2, 0.0), goal=(40.0, 3.2, 40.0, 1.0))  # the goal is on path 0, the ego on path 1
    row = {k: v[0] for k, v in obs.items()}
    chosen = []
    for _ in range(12):
        planner.choose_path(state, row)
        chosen.append(state.path)
    assert chosen[:9] == [1] * 9 and chosen[9:] == [0] * 3


def test_vcr_bezier_plan_is_about_one_metre_per_point():
    planner = vcr.VCRPlanner()
    plan = planner.plan(planner.new_state(), {k: v[0] for k, v in observation().items()})
    assert plan.shape == (18, 3)
    np.testing.assert_allclose(np.diff(plan[:, 0]), 1.0, atol=1e-6)


# ----------------------------------------------------------------------------- TF
def test_tf_hold_release_and_ignore_timeline():
    planner = TFPlanner()
    blocked = observation(neighbours=[(9.0, 0.0, 0.0)], speed=0.0)
    for _ in range(20):  # past the novice steps
        action = planner.act(blocked)[0]
    state = planner._states[0]
    assert state.stopped_by == "rule" and np.all(action == 0)
    assert 0 < state.hold <= HOLD_STEPS
    free = observation(speed=0.0)
    action = planner.act(free)[0]  # the blocker left: released at once
    assert state.hold == 0 and action[0] > 0
    planner = TFPlanner()
    for _ in range(HOLD_STEPS + 2):
        planner.act(blocked)
    state = planner._states[0]
    assert state.ignore == IGNORE_STEPS - 1  # the hold ran out: a 10-step window ignoring the rule
    assert planner.act(blocked)[0][0] == 0.0  # still stopped: the leader caps the lane speed at 0


def test_tf_halves_speed_in_turns_and_thins_out_with_density():
    planner = TFPlanner()
    obs = observation()
    straight = planner.act(obs)[0]
    assert np.hypot(*straight[:2]) == pytest.approx(1.389, abs=1e-3)
    turn = observation()
    h = np.minimum(np.arange(51) * 0.1, 1.5)
    turn["waypoints"][0, 0, :, 0] = np.concatenate([[0], np.cumsum(np.cos(h[:-1]))])
    turn["waypoints"][0, 0, :, 1] = np.concatenate([[0], np.cumsum(np.sin(h[:-1]))])
    turn["waypoints"][0, 0, :, 2] = h
    step = TFPlanner().act(turn)[0]
    assert np.hypot(*step[:2]) == pytest.approx(0.5 * 1.389, abs=1e-3)
    crowded = observation(neighbours=[(-15.0, 3.2, 10.0)] * 5 + [(-18.0, -3.2, 10.0)] * 5)
    step = TFPlanner().act(crowded)[0]
    assert np.hypot(*step[:2]) == pytest.approx(0.8 * 1.389, abs=1e-3)


def test_tf_features_layout():
    obs = observation(neighbours=[(10.0, 0.0, 5.0)])
    row = {k: v[0] for k, v in obs.items()}
    f = stop_move_features(row, row["waypoints"][0, :5])
    assert f.shape == (53,)
    np.testing.assert_allclose(f[:7], [-0.0, 10.0, 0.0, -5.0, 0.0, 4.6, 1.9])
    np.testing.assert_allclose(f[35:45], [0, 0, 0, 1, 0, 2, 0, 3, 0, 4])
    np.testing.assert_allclose(f[50:], [13.89, 4.6, 1.9], rtol=1e-6)
