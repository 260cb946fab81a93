"""The episode recorder: the row contract (row k = after step k+1) and the following columns by
lane continuity, on real scenarios."""

from __future__ import annotations

import numpy as np
import pytest

from agents.keep_lane import KeepLanePolicy
from smarts.benchmark.agents import PolicySetup
from smarts.benchmark.jobs import Job, job_inputs
from smarts.benchmark.metrics import read_episode, score_episode
from smarts.benchmark.metrics.params import MetricParams
from smarts.benchmark.metrics.scores import time_gap_to_margin
from smarts.benchmark.recorder import EpisodeRecorder
from smarts.benchmark.runner import build_env, run_episode
from smarts.benchmark.suites import load_suite

CONTINUITY = """
name: continuity
task: adaptive
episodes: 1
seed: 0
scenarios:
  - name: boundary
    difficulty: easy
    time_limit: 8
    follow: {agent_0: lead, agent_1: lead}
    scenario:
      map: builtin:highway_merge_exit
      agents:
        - mission: {start: {road: main_0, lane: 2, offset: 160, speed: 10}, goal: {endless: true}}
        - mission: {start: {road: main_0, lane: 1, offset: 172, speed: 10}, goal: {endless: true}}
      traffic:
        engine: builtin
        vehicle_types:
          lead: {base: passenger, max_speed: 10, accel: 1.5, decel: 3.0, tau: 1.2}
        trips:
          - {id: lead, route: [main_0, main_4], depart_lane: 2, depart_pos: 185, depart_speed: 10, vehicle_type: lead}
"""

SHORT = """
name: short
task: collaborative
episodes: 1
seed: 3
scenarios:
  - name: straight
    difficulty: easy
    time_limit: 2.05
    scenario:
      map: builtin:straight_2lane
      agents:
        - mission: {start: {road: main, offset: 10, speed: 8}, goal: {road: main, offset: 150}}
"""


def _drive(entry, policy, listener=None):
    env = build_env(entry, PolicySetup("relative_target_pose"))
    obs, _ = env.reset(seed=0)
    recorder = EpisodeRecorder(env.sim, env.possible_agents, scenario=entry.name, task="adaptive", episode=0,
                               seed=0, time_limit=entry.time_limit, follow=entry.follow)  # fmt: skip
    env.add_step_listener(lambda sim: recorder.record())
    if listener is not None:
        env.add_step_listener(listener)
    try:
        while env.agents and env.sim.time < entry.time_limit - 1e-9:
            batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
            obs, *_ = env.step(dict(zip(env.agents, policy.act(batch))))
        return recorder.finish(), env.sim.road_map
    finally:
        env.close()


def test_lead_straight_ahead_stays_in_lane_across_segment_boundaries(tmp_path):
    path = tmp_path / "continuity.yaml"
    path.write_text(CONTINUITY)
    entry = load_suite(path).scenarios[0]
    seen = []  # per step: lane of agent_0, agent_1 and the lead, and their x and lengths

    def listener(sim):
        t = sim.table
        rows = [sim.agent_row[sim.agent_index[a]] for a in ("agent_0", "agent_1")] + [t.row_of["lead"]]
        seen.append([(int(t.lane[r]), float(t.x[r]), float(t.y[r]), float(t.length[r])) for r in rows])

    log, road_map = _drive(entry, KeepLanePolicy(speed=10.0), listener)
    follower, neighbour = log.agents["agent_0"], log.agents["agent_1"]
    assert follower.num_steps == len(seen) == 80
    roads = [
        (road_map.road_ids[road_map.lane_road[s[0][0]]], road_map.road_ids[road_map.lane_road[s[2][0]]]) for s in seen
    ]
    # The lead crosses from main_0 into main_1 (new lane ids, one more lane) before the follower does.
    assert ("main_0", "main_1") in roads and roads[-1] == ("main_1", "main_1")
    assert any(s[0][0] != s[2][0] for s in seen)
    # ... and stays in the follower's lane on every row.
    assert follower.lead_in_lane_and_visible.all()
    # The gap is bumper to bumper along the (straight) lanes.
    gap_m = np.array([s[2][1] - s[0][1] - 0.5 * (s[2][3] + s[0][3]) for s in seen])
    expected, inside = time_gap_to_margin(gap_m, follower.speed, MetricParams())
    assert (follower.in_follow_margin == inside).all()
    outside = ~inside
    np.testing.assert_allclose(follower.follow_time_gap[outside], expected[outside], rtol=1e-6)
    # The lead in the neighbouring lane, in sight, is never "in lane".
    distance = np.array([np.hypot(s[2][1] - s[1][1], s[2][2] - s[1][2]) for s in seen])
    assert (distance < 50.0).all() and (np.array([s[1][0] != s[2][0] for s in seen])).all()
    assert not neighbour.lead_in_lane_and_visible.any() and np.isnan(neighbour.follow_time_gap).all()
    assert score_episode(log)["SFD"] > 0.0


def test_rows_start_after_the_first_step_and_end_at_the_time_limit(tmp_path):
    path = tmp_path / "short.yaml"
    path.write_text(SHORT)
    suite = load_suite(path)
    job = Job("zoo:keep-lane", suite.source, 0, 0, 3, str(tmp_path / "log.npz"))
    result = run_episode(job)
    assert result["failure"] is None
    log = read_episode(tmp_path / "log.npz")
    trace = log.agents["agent_0"]
    # 2.05 s at 0.1 s steps: rows after steps 1..20 (time 0.1 .. 2.0); the 21st step (2.1 s) is
    # past the limit and is not a row; the reset state (time 0) is not a row either.
    assert trace.num_steps == 20
    np.testing.assert_allclose(trace.time, 0.1 * np.arange(1, 21))
    # The initial route distance is the reset state's (start offset 10, goal offset 150 on the
    # same lane: 140 m, not the 290 m to the lane's end), not the first row's.
    assert log.initial_route_distance["agent_0"] == pytest.approx(140.0, abs=0.01)
    driven = trace.x - 10.0
    np.testing.assert_allclose(trace.route_distance_to_goal, 140.0 - driven, atol=0.01)
    assert log.info == {"agent": "zoo:keep-lane", "inputs": job_inputs(job), "suite": "short",
                        "suite_source": suite.source, "action_space": "relative_target_pose",
                        "controller": "direct", "interface": None, "lane_relative": None, "comms": None}  # fmt: skip
    assert log.end_time == pytest.approx(2.0)


def test_recording_before_any_step_writes_nothing(tmp_path):
    path = tmp_path / "short.yaml"
    path.write_text(SHORT)
    entry = load_suite(path).scenarios[0]
    env = build_env(entry, PolicySetup("relative_target_pose"))
    env.reset(seed=0)
    try:
        recorder = EpisodeRecorder(env.sim, env.possible_agents, scenario="s", task="collaborative", episode=0,
                                   seed=0, time_limit=entry.time_limit)  # fmt: skip
        recorder.record()  # at the reset state: not a row
        assert recorder.rows == {"agent_0": []}
        with pytest.raises(ValueError, match="disagrees with the missions' leads"):
            EpisodeRecorder(env.sim, env.possible_agents, scenario="s", task="adaptive", episode=0, seed=0,
                            time_limit=1.0, follow={"agent_0": "lead"})  # fmt: skip
    finally:
        env.close()


RAM = """
name: ram
task: adaptive
episodes: 1
seed: 0
scenarios:
  - name: ram
    difficulty: easy
    time_limit: 12
    follow: {agent_0: lead}
    scenario:
      map: builtin:straight_2lane
      agents:
        - mission: {start: {road: main, lane: 0, offset: 10, speed: 12}, goal: {endless: true}}
      traffic:
        engine: builtin
        vehicle_types:
          lead: {base: passenger, max_speed: 6, accel: 1.5, decel: 3.0, tau: 1.2}
        trips:
          - {id: lead, route: [main], depart_lane: 0, depart_pos: 40, depart_speed: 6, vehicle_type: lead}
"""


def test_a_follower_that_rams_its_lead_has_not_completed_the_scenario(tmp_path, monkeypatch):
    import zoo.registry

    monkeypatch.setitem(zoo.registry.ZOO, "ram", ("tests.benchmark.broken_agent", "RammingPolicy", ""))
    path = tmp_path / "ram.yaml"
    path.write_text(RAM)
    suite = load_suite(path)
    result = run_episode(Job("zoo:ram", suite.source, 0, 0, 0, str(tmp_path / "ram.npz")))
    assert result["failure"] is None
    log = read_episode(tmp_path / "ram.npz")
    trace = log.agents["agent_0"]
    crash = float(trace.time[-1])
    assert crash < 4.0  # 30 m closed at 6 to 10 m/s more than the lead
    # The scenario ran on to its time limit: the lead's position then is the follower's goal...
    assert log.end_time == pytest.approx(12.0)
    assert trace.route_distance_to_goal[-1] > 6.0 * (12.0 - crash) - 5.0
    scores = score_episode(log)
    assert scores["PR"] < 0.5
    # ... and SFD counts every step it missed as lost contact.
    assert scores["SFD"] <= crash / 12.0 + 1e-9


def test_nearest_path_points_are_numpys_argmin_bit_for_bit():
    """The compiled nearest-point search behind route_distance_to_goal gives numpy's argmin (the
    first of equal distances) and its squared distance exactly, ties included."""
    from smarts.benchmark.recorder import _nearest_points

    rng = np.random.default_rng(1)
    for trial in range(60):
        n, m = int(rng.integers(1, 200)), int(rng.integers(1, 300))
        scale = float(rng.choice([1.0, 50.0, 300.0]))
        xy, path = rng.normal(size=(n, 2)) * scale, rng.normal(size=(m, 2)) * scale
        if trial % 3 == 0:  # integer grids: many equal distances
            xy, path = np.round(xy / scale * 3), np.round(path / scale * 3)
        d2 = ((xy[:, None, :] - path[None, :, :]) ** 2).sum(axis=2)
        nearest = d2.argmin(axis=1)
        got, got_d2 = _nearest_points(xy, path)
        assert np.array_equal(got, nearest) and np.array_equal(got_d2, d2[np.arange(n), nearest]), trial
