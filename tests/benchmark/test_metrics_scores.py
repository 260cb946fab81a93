"""Hand-computed checks of every metric formula and its edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from smarts.benchmark.metrics import (
    LogError,
    MetricParams,
    Weights,
    agent_costs,
    follow_margin,
    in_follow_margin,
    score_episode,
    score_suite,
    time_gap_to_margin,
)
from smarts.benchmark.metrics.params import HumannessParams
from smarts.benchmark.metrics.scores import comfort_window, penalty_steps, s_bench
from smarts.benchmark.metrics.synthetic import make_episode, make_trace

P = MetricParams()


def one(trace, **kw):
    return make_episode({"a": trace}, **kw)


# ------------------------------------------------------------------------------------ PR
def test_progress_two_vehicles_hand_computed():
    # a: 100 m route, 25 m left -> 0.25; b: 50 m route, ends 60 m away (drove backwards) -> capped 1.
    a = make_trace(5, route_distance_to_goal=np.array([90.0, 70.0, 50.0, 30.0, 25.0]))
    b = make_trace(5, route_distance_to_goal=np.array([52.0, 55.0, 57.0, 59.0, 60.0]))
    log = make_episode({"a": a, "b": b}, initial_route_distance={"a": 100.0, "b": 50.0})
    costs = agent_costs(log, P)
    assert costs["a"].progress == pytest.approx(0.25)
    assert costs["b"].progress == pytest.approx(1.0)
    assert score_episode(log, P)["PR"] == pytest.approx(1 - (0.25 + 1.0) / 2)


def test_progress_goal_reached_counts_as_route_completed():
    # Arrived inside the 2 m goal radius with 1.5 m left: no shortfall.
    goal = np.array([False, False, True])
    log = one(
        make_trace(3, route_distance_to_goal=np.array([40.0, 10.0, 1.5]), goal_reached=goal),
        initial_route_distance=60.0,
    )
    assert score_episode(log, P)["PR"] == pytest.approx(1.0)


def test_goal_never_reached():
    log = one(
        make_trace(20, route_distance_to_goal=np.full(20, 30.0)),
        initial_route_distance=120.0,
    )
    s = score_episode(log, P)
    assert s["PR"] == pytest.approx(1 - 30.0 / 120.0)
    assert s["MTE"] == 0.0  # T_arrive = T_limit


def test_zero_length_route_is_already_there():
    log = one(make_trace(4, speed=0.0, initial_route_distance=0.0), initial_route_distance=0.0)
    assert agent_costs(log, P)["a"].progress == 0.0
    assert score_episode(log, P)["PR"] == 1.0


def test_vehicle_that_never_moves():
    n = 30
    trace = make_trace(n, speed=0.0, initial_route_distance=80.0)
    assert np.all(trace.route_distance_to_goal == 80.0) and np.all(trace.x == 0.0)
    s = score_episode(one(trace, initial_route_distance=80.0), P)
    assert s["PR"] == 0.0
    assert s["MTE"] == 0.0
    # Standing still on the lane centre is comfortable and lawful.
    assert s["Humanness"] == 1.0 and s["RC"] == 1.0


# ----------------------------------------------------------------------------- Humanness
def test_comfort_window_by_hand():
    # T_trv = 6 steps, T_p = 3, one uncomfortable step at t = 2 (1-based).
    # u_t, t = 1..9: windows [1,1] [1,2] [1,3] [1,4] [2,5] [3,6] [4,6] [5,6] [6,6]
    u = comfort_window(np.array([0, 1, 0, 0, 0, 0], dtype=bool), 3)
    assert u.tolist() == [0, 1, 1, 1, 1, 0, 0, 0, 0]
    # A second spike at the last step keeps u on through the padding after the trace.
    u = comfort_window(np.array([0, 1, 0, 0, 0, 1], dtype=bool), 3)
    assert u.tolist() == [0, 1, 1, 1, 1, 1, 1, 1, 1]
    assert comfort_window(np.zeros(4, dtype=bool), 3).tolist() == [0] * 7
    assert comfort_window(np.array([1, 0, 0], dtype=bool), 0).tolist() == [1, 0, 0]


def test_comfort_spike_and_penalty_window():
    params = MetricParams(humanness=HumannessParams(penalty_period_s=0.3))  # 3 steps at dt 0.1
    assert penalty_steps(0.1, params) == 3
    accel = np.zeros(6)
    accel[1] = 2.5  # > 2.0 m/s^2 at step 2
    log = one(make_trace(6, accel_long=accel))
    assert agent_costs(log, params)["a"].comfort == pytest.approx(4 / 9)
    # Humanness = 1 - (comfort + lane centre 0) / 2
    assert score_episode(log, params)["Humanness"] == pytest.approx(1 - (4 / 9) / 2)
    # A lateral-jerk spike at the last step too: u on from t = 2 to 9.
    jerk_lat = np.zeros(6)
    jerk_lat[5] = -1.0
    log = one(make_trace(6, accel_long=accel, jerk_lat=jerk_lat))
    assert agent_costs(log, params)["a"].comfort == pytest.approx(8 / 9)


def test_comfort_thresholds_are_strict():
    # Every ratio exactly 1 is still comfortable (u needs dyn > 1).
    trace = make_trace(
        5,
        accel_long=np.full(5, -2.0),
        accel_lat=np.full(5, 1.47),
        jerk_long=np.full(5, 0.9),
        jerk_lat=np.full(5, -0.9),
    )
    assert agent_costs(one(trace), P)["a"].comfort == 0.0
    trace = make_trace(5, jerk_long=np.array([0, 0, 0.91, 0, 0]))
    # Default T_p = 3 s = 30 steps: u on for t = 3..33 -> 31 of 35.
    assert penalty_steps(0.1, P) == 30
    assert agent_costs(one(trace), P)["a"].comfort == pytest.approx(31 / 35)


def test_lane_centre_offset_hand_computed():
    offset = np.array([0.0, 1.0, -3.0, np.nan])
    off_road = np.array([False, False, False, True])
    width = np.array([4.0, 4.0, 4.0, np.nan])
    log = one(make_trace(4, lane_offset=offset, lane_width=width, off_road=off_road))
    c = agent_costs(log, P)["a"]
    assert c.lane_centre == pytest.approx((0 + 0.5 + 1 + 1) / 4)
    assert score_episode(log, P)["Humanness"] == pytest.approx(1 - (0 + 0.625) / 2)


def test_always_off_road():
    n = 8
    log = one(
        make_trace(
            n,
            lane_offset=np.full(n, np.nan),
            lane_width=np.full(n, np.nan),
            off_road=np.ones(n, bool),
        )
    )
    c = agent_costs(log, P)["a"]
    assert c.lane_centre == 1.0 and c.off_road == 1.0
    s = score_episode(log, P)
    assert s["Humanness"] == pytest.approx(0.5)
    assert s["RC"] == pytest.approx(1 - 1 / 3)


# ------------------------------------------------------------------------------------ RC
def test_rules_hand_computed():
    speed = np.array([10.0, 12.5, 15.0, 20.0])  # limit 10: excess / 5 -> 0, .5, 1, 2 -> capped 1
    wrong = np.array([False, True, False, False])
    log = one(make_trace(4, speed=speed, speed_limit=np.full(4, 10.0), wrong_way=wrong))
    c = agent_costs(log, P)["a"]
    assert c.overspeed == pytest.approx(0.625)
    assert (c.wrong_way, c.off_road) == (1.0, 0.0)
    assert score_episode(log, P)["RC"] == pytest.approx(1 - (0.625 + 1 + 0) / 3)


def test_speeding_by_exactly_half_the_limit_saturates():
    log = one(make_trace(5, speed=30.0, speed_limit=np.full(5, 20.0)))
    assert agent_costs(log, P)["a"].overspeed == 1.0
    log = one(make_trace(5, speed=25.0, speed_limit=np.full(5, 20.0)))
    assert agent_costs(log, P)["a"].overspeed == pytest.approx(0.5)


def test_one_partial_off_road_step_counts_once():
    po = np.zeros(10, bool)
    po[4] = True
    log = one(make_trace(10, partial_off_road=po))
    assert agent_costs(log, P)["a"].off_road == 1.0
    assert score_episode(log, P)["RC"] == pytest.approx(2 / 3)


# ----------------------------------------------------------------------------------- MTE
def test_mte_first_arrival_time():
    goal = np.zeros(50, bool)
    goal[24:] = True  # first True at row 24 -> time 2.5 s
    log = one(make_trace(50, goal_reached=goal), time_limit=10.0)
    assert agent_costs(log, P)["a"].time == pytest.approx(0.25)
    assert score_episode(log, P)["MTE"] == pytest.approx(0.75)


# ----------------------------------------------------------------------------------- SFD
def test_following_helpers():
    assert follow_margin(0.0, P) == 2.5
    assert follow_margin(np.array([10.0, -1.0]), P).tolist() == [12.5, 2.5]
    gaps = np.array([18.5, 12.5, 40.0, 5.0, np.nan])
    speed = np.array([10.0, 10.0, 0.0, 10.0, 10.0])
    tg, inside = time_gap_to_margin(gaps, speed, P)
    assert tg[0] == pytest.approx(0.6)
    assert (tg[1], tg[2], tg[3]) == (0.0, math.inf, 0.0)
    assert math.isnan(tg[4])
    assert inside.tolist() == [False, True, False, True, False]
    assert in_follow_margin(gaps, speed, P).tolist() == inside.tolist()
    assert time_gap_to_margin(27.5, 10.0, P.following) == (pytest.approx(1.5), False)
    assert time_gap_to_margin(2.5, 0.0, P) == (0.0, True)
    assert time_gap_to_margin(3.0, 0.0, P) == (math.inf, False)


def test_sfd_hand_computed():
    # Gaps from the helpers, as the env logger would compute them (ego at 10 m/s, FM = 12.5 m).
    gap_m = np.array([10.0, 18.5, 27.5, 52.5, np.nan, 42.5])
    speed = np.full(6, 10.0)
    visible = np.array([True, True, True, True, False, True])
    gap_m_seen = np.where(visible, gap_m, np.nan)
    tg, inside = time_gap_to_margin(gap_m_seen, speed, P)
    tg = np.where(visible & ~inside, tg, np.nan)
    # steps: inside FM -> 1; 0.6 s -> 0.2; 1.5 s -> 0.5; 4 s > t_max -> 1; lead out of lane -> 1;
    # exactly t_max (3 s) -> 1.
    expected = [1.0, 0.2, 0.5, 1.0, 1.0, 1.0]
    trace = make_trace(
        6,
        with_following=True,
        follow_time_gap=tg,
        in_follow_margin=inside,
        lead_in_lane_and_visible=visible,
    )
    log = one(trace, task="adaptive")
    assert agent_costs(log, P)["a"].follow_gap == pytest.approx(np.mean(expected))
    s = score_episode(log, P)
    assert s["SFD"] == pytest.approx(1 - np.mean(expected))
    assert "MTE" not in s


def test_sfd_counts_the_steps_a_crashed_follower_missed_as_lost():
    # 5 steps at the best gap (cost 0 each), then the follower's rows stop (it rammed its lead)
    # while the scenario ran on to 2.0 s: the 15 missing steps count as lost contact (cost 1).
    n = 5
    trace = make_trace(
        n,
        with_following=True,
        follow_time_gap=np.zeros(n),
        in_follow_margin=np.zeros(n, bool),
        lead_in_lane_and_visible=np.ones(n, bool),
    )
    assert score_episode(one(trace, task="adaptive"), P)["SFD"] == 1.0  # no end time: as logged
    crashed = one(trace, task="adaptive", end_time=2.0)
    assert agent_costs(crashed, P)["a"].follow_gap == pytest.approx(15 / 20)
    assert score_episode(crashed, P)["SFD"] == pytest.approx(0.25)
    # A follower that lasted to the end misses nothing.
    assert score_episode(one(trace, task="adaptive", end_time=0.5), P)["SFD"] == 1.0


def test_end_time_is_validated():
    trace = make_trace(5)
    with pytest.raises(LogError, match=r"metadata\.end_time.*after the time limit"):
        one(trace, end_time=11.0).validate()
    with pytest.raises(LogError, match=r"metadata\.end_time.*before the last logged row"):
        one(trace, end_time=0.2).validate()


def test_sfd_lead_out_of_sight_throughout():
    n = 5
    trace = make_trace(
        n,
        with_following=True,
        follow_time_gap=np.full(n, np.nan),
        lead_in_lane_and_visible=np.zeros(n, bool),
    )
    assert score_episode(one(trace, task="adaptive"), P)["SFD"] == 0.0


# --------------------------------------------------------------------------- S_bench, suite
def test_s_bench_weights_collaborative_and_adaptive():
    # PR 0.5 (50 of 100 m left, goal not reached), RC 1, Humanness 1, MTE 0.
    trace = make_trace(5, route_distance_to_goal=np.full(5, 50.0), with_following=True)
    s = score_episode(one(trace, initial_route_distance=100.0), P)
    assert (s["PR"], s["RC"], s["Humanness"], s["MTE"]) == (0.5, 1.0, 1.0, 0.0)
    assert s["S_bench"] == pytest.approx(0.1 * 0.5 + 0.45 + 0.15 + 0.3 * 0.0)
    # Adaptive: every step 1.5 s from the margin -> SFD 0.5.
    s = score_episode(one(trace, task="adaptive", initial_route_distance=100.0), P)
    assert s["SFD"] == pytest.approx(0.5)
    assert s["S_bench"] == pytest.approx(0.1 * 0.5 + 0.45 + 0.15 + 0.3 * 0.5)
    # Weights need not sum to 1: S_bench divides by their sum.
    params = MetricParams(weights=Weights(pr=1.0, rc=0.0, humanness=0.0, mte=1.0, sfd=3.0))
    assert score_episode(one(trace, initial_route_distance=100.0), params)["S_bench"] == pytest.approx(0.25)
    s = score_episode(one(trace, task="adaptive", initial_route_distance=100.0), params)
    assert s["S_bench"] == pytest.approx((0.5 + 3 * 0.5) / 4)


def test_s_bench_puts_each_weight_on_its_own_metric():
    """Four different values, so a weight on the wrong metric changes the result."""
    metrics = {"PR": 0.9, "RC": 0.7, "Humanness": 0.4, "MTE": 0.2, "SFD": 0.6}
    assert s_bench(metrics, "collaborative", P) == pytest.approx(0.1 * 0.9 + 0.45 * 0.7 + 0.15 * 0.4 + 0.3 * 0.2)
    assert s_bench(metrics, "adaptive", P) == pytest.approx(0.1 * 0.9 + 0.45 * 0.7 + 0.15 * 0.4 + 0.3 * 0.6)
    params = MetricParams(weights=Weights(pr=1.0, rc=2.0, humanness=3.0, mte=4.0, sfd=5.0))
    assert s_bench(metrics, "collaborative", params) == pytest.approx((0.9 + 1.4 + 1.2 + 0.8) / 10)
    assert s_bench(metrics, "adaptive", params) == pytest.approx((0.9 + 1.4 + 1.2 + 3.0) / 11)


def _progress_episode(scenario: str, episode: int, left: float) -> object:
    trace = make_trace(3, route_distance_to_goal=np.full(3, left))
    return make_episode({"a": trace}, scenario=scenario, episode=episode, initial_route_distance=100.0)


def test_suite_averages_episodes_within_a_scenario_first():
    logs = [
        _progress_episode("short", 0, 0.0),  # PR 1
        _progress_episode("long", 0, 100.0),  # PR 0
        _progress_episode("long", 1, 100.0),  # PR 0
        _progress_episode("long", 2, 0.0),  # PR 1
    ]
    suite = score_suite(logs, P)
    assert suite.episodes == {"long": 3, "short": 1}
    assert suite.scenarios["short"]["PR"] == 1.0
    assert suite.scenarios["long"]["PR"] == pytest.approx(1 / 3)
    assert suite.overall["PR"] == pytest.approx((1 + 1 / 3) / 2)  # not the episode mean 0.5
    assert list(suite.overall) == ["PR", "RC", "Humanness", "MTE", "S_bench"]
    # Linear metrics: S_bench of the means equals the mean of per-scenario S_bench.
    assert suite.overall["S_bench"] == pytest.approx(np.mean([r["S_bench"] for r in suite.scenarios.values()]))
    table = suite.format_table()
    assert "overall" in table and "long" in table and "short" in table


def test_failed_episode_scores_worst_by_default():
    logs = [_progress_episode("s", 0, 0.0), _progress_episode("s", 1, 0.0)]
    logs[1].failure = "agent raised RuntimeError"
    s = score_episode(logs[1], P)
    assert all(s[m] == 0.0 for m in ("PR", "RC", "Humanness", "MTE", "S_bench"))
    good = score_episode(logs[0], P)
    suite = score_suite(logs, P)
    assert suite.episodes == {"s": 2}
    for m in suite.metric_names:
        assert suite.overall[m] == pytest.approx(good[m] / 2)
    assert suite.failed == [
        {
            "scenario": "s",
            "episode": 1,
            "seed": 0,
            "failure": "agent raised RuntimeError",
            "source": None,
            "excluded": False,
        }
    ]


def test_failed_episode_excluded_by_policy_is_reported():
    logs = [
        _progress_episode("s", 0, 50.0),
        _progress_episode("s", 1, 0.0),
        _progress_episode("t", 0, 0.0),
    ]
    logs[1].failure = "timeout talking to the agent"
    logs[2].failure = "agent raised"
    params = MetricParams(failed_episodes="exclude")
    suite = score_suite(logs, params)
    assert suite.episodes == {"s": 1}  # scenario t had no episode left
    assert suite.overall["PR"] == pytest.approx(0.5)
    assert [(f["scenario"], f["episode"], f["excluded"]) for f in suite.failed] == [
        ("s", 1, True),
        ("t", 0, True),
    ]
    assert "excluded" in suite.format_table()
    with pytest.raises(ValueError, match="nothing to score"):
        score_suite(logs[1:], params)


def test_failed_episode_without_any_agent():
    log = make_episode({}, failure="reset raised", initial_route_distance={})
    assert score_episode(log, P)["S_bench"] == 0.0


def test_suite_rejects_mixed_tasks_duplicates_and_bad_logs():
    a = _progress_episode("s", 0, 0.0)
    b = make_episode({"a": make_trace(3, with_following=True)}, scenario="f", task="adaptive")
    with pytest.raises(ValueError, match="mix tasks"):
        score_suite([a, b], P)
    with pytest.raises(LogError, match="appears twice"):
        score_suite([a, _progress_episode("s", 0, 10.0)], P)
    with pytest.raises(ValueError, match="no episode"):
        score_suite([], P)
    bad = _progress_episode("s", 1, 0.0)
    bad.agents["a"].speed[1] = np.nan
    with pytest.raises(LogError, match=r"agent 'a': column 'speed'"):
        score_suite([a, bad], P)


def test_multi_agent_episode_means_over_vehicles():
    a = make_trace(4, speed=15.0, speed_limit=np.full(4, 10.0))  # overspeed 1
    b = make_trace(4)  # overspeed 0
    log = make_episode({"a": a, "b": b})
    s = score_episode(log, P)
    assert s["cost.overspeed"] == pytest.approx(0.5)
    assert s["RC"] == pytest.approx(1 - 0.5 / 3)


def _pr_episodes(scenario: str, lefts: list[float], seed0: int = 100) -> list:
    logs = [_progress_episode(scenario, e, left) for e, left in enumerate(lefts)]
    for e, log in enumerate(logs):
        log.seed = seed0 + e
    return logs


def test_confidence_intervals_stratified_bootstrap_by_hand():
    # Scenario "a": PR 1 in both episodes (no spread); "b": PR 0 and 1. A resample of "b" has mean
    # 0, 0.5 or 1 (p = 1/4, 1/2, 1/4), so the overall PR (scenarios equal) is 0.5, 0.75 or 1.0 and
    # its central 95% is [0.5, 1.0]; per episode resampling would mix the scenarios' weights.
    logs = _pr_episodes("a", [0.0, 0.0]) + _pr_episodes("b", [100.0, 0.0], seed0=200)
    suite = score_suite(logs, P)
    assert suite.overall["PR"] == pytest.approx(0.75)
    assert suite.overall_ci["PR"] == pytest.approx((0.5, 1.0))
    assert suite.scenario_ci["a"]["PR"] == pytest.approx((1.0, 1.0))
    assert suite.scenario_ci["b"]["PR"] == pytest.approx((0.0, 1.0))
    # S_bench is recomputed per resample: only PR varies, so its interval is S_bench at the PR ends.
    other = {m: suite.overall[m] for m in ("RC", "Humanness", "MTE")}
    ends = [s_bench({"PR": pr, **other}, "collaborative", P) for pr in (0.5, 1.0)]
    assert suite.overall_ci["S_bench"] == pytest.approx(tuple(ends))
    for m in suite.metric_names:
        lo, hi = suite.overall_ci[m]
        assert lo <= suite.overall[m] <= hi
    assert suite.seeds == {"a": {0: 100, 1: 101}, "b": {0: 200, 1: 201}}
    assert [e["PR"] for e in suite.episode_scores["b"]] == [0.0, 1.0]
    assert suite.ci["resamples"] == 2000 and "stratified" in suite.ci["method"]


def test_confidence_intervals_are_reproducible_and_narrow_with_more_episodes():
    rng = np.random.default_rng(1)
    lefts = list(rng.uniform(0, 100, 30))
    few = score_suite(_pr_episodes("s", lefts[:4]), P)
    again = score_suite(_pr_episodes("s", lefts[:4]), P)
    assert few.overall_ci == again.overall_ci  # fixed bootstrap seed: reports repeat exactly
    many = score_suite(_pr_episodes("s", lefts), P)
    width = lambda s: s.overall_ci["PR"][1] - s.overall_ci["PR"][0]  # noqa: E731
    assert 0 < width(many) < width(few)
    other_seed = score_suite(_pr_episodes("s", lefts[:4]), P, ci_seed=5)
    assert other_seed.overall == few.overall
    with pytest.raises(ValueError, match="ci level"):
        score_suite(_pr_episodes("s", lefts[:4]), P, ci_level=1.5)


def test_failed_episodes_enter_the_bootstrap_as_worst():
    logs = _pr_episodes("s", [0.0, 0.0, 0.0])
    logs[2].failure = "agent raised"
    suite = score_suite(logs, P)
    assert suite.scenario_ci["s"]["S_bench"][0] == pytest.approx(0.0)  # all three resampled as the failure
    assert suite.failed[0]["seed"] == 102
    table = suite.format_table()
    assert "[0.000," in table and "s: 0=100, 1=101, 2=102" in table and "#2 (seed 102)" in table
    assert "bootstrap" in table
