"""RC's rules beyond the paper's three terms: the red-light rule (entering a junction lane on red,
only on maps with signals) and the end-of-map rule (driving off the end of the map at the end of
the route is leaving the map, not the road), in the metrics and on real scenarios."""

from __future__ import annotations

import numpy as np
import pytest

from agents.keep_lane import KeepLanePolicy
from smarts.benchmark.agents import PolicySetup
from smarts.benchmark.metrics import LogError, MetricParams, score_episode, validate_episode
from smarts.benchmark.metrics.synthetic import make_episode, make_trace
from smarts.benchmark.recorder import EpisodeRecorder
from smarts.benchmark.runner import build_env
from smarts.benchmark.suites import load_suite

CROSSING = """
name: crossing
task: collaborative
episodes: 1
seed: 0
scenarios:
  - name: cross
    difficulty: easy
    time_limit: 12
    scenario:
      map: builtin:intersection_4way_1lane_signal
      agents:
        - mission: {start: {road: west_in, offset: 80, speed: 10}, goal: {road: east_out, offset: 30}}
        - mission: {start: {road: south_in, offset: 50, speed: 10}, goal: {road: north_out, offset: 30}}
"""


class SignalBlind(KeepLanePolicy):
    """Keep-lane that does not see the signals: it drives through a red light."""

    def act(self, obs):
        return super().act({k: v for k, v in obs.items() if k != "signal"})


def drive(entry, policy, task):
    env = build_env(entry, PolicySetup("relative_target_pose"))
    obs, _ = env.reset(seed=0)
    recorder = EpisodeRecorder(env.sim, env.possible_agents, scenario=entry.name, task=task, episode=0, seed=0,
                               time_limit=entry.time_limit, follow=entry.follow)  # fmt: skip
    env.add_step_listener(lambda sim: recorder.record())
    try:
        while env.agents and env.sim.time < entry.time_limit - 1e-9:
            batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
            obs, *_ = env.step(dict(zip(env.agents, policy.act(batch))))
        return recorder.finish()
    finally:
        env.close()


# ------------------------------------------------------------------------------------- metrics
def test_the_red_light_term_enters_rc_only_where_there_are_signals():
    red = np.zeros(20, dtype=bool)
    red[7] = True
    trace = make_trace(20, red_light=red)
    assert score_episode(make_episode({"a": trace}, signals=0))["RC"] == 1.0
    with_signals = score_episode(make_episode({"a": trace}, signals=4))
    assert with_signals["RC"] == pytest.approx(1 - 1 / 4) and with_signals["cost.red_light"] == 1.0
    heavy = MetricParams.from_dict({"rules": {"weights": {"red_light": 2.0}}})
    assert score_episode(make_episode({"a": trace}, signals=4), heavy)["RC"] == pytest.approx(1 - 2 / 5)
    # Without a violation the fourth term changes nothing: RC is the paper's.
    clean = make_trace(20, partial_off_road=np.arange(20) == 3)
    assert score_episode(make_episode({"a": clean}, signals=4))["RC"] == pytest.approx(1 - 1 / 4)
    assert score_episode(make_episode({"a": clean}, signals=0))["RC"] == pytest.approx(1 - 1 / 3)


def test_leaving_the_map_on_the_last_row_is_not_leaving_the_road():
    off = np.arange(20) == 19
    left = np.arange(20) == 19
    assert score_episode(make_episode({"a": make_trace(20, partial_off_road=off, left_map=left)}))["RC"] == 1.0
    assert score_episode(make_episode({"a": make_trace(20, partial_off_road=off)}))["RC"] == pytest.approx(2 / 3)
    # A vehicle that left the map has no rows after: left_map before the last row is refused.
    early = make_episode({"a": make_trace(20, left_map=np.arange(20) == 5)})
    with pytest.raises(LogError, match="left_map.*set on row 5 of 20"):
        validate_episode(early)


# ----------------------------------------------------------------------------- real scenarios
def test_keep_lane_on_an_empty_road_leaves_the_map_without_breaking_a_rule():
    """adaptive a01: the lead drives off the end of the 300 m road and keep-lane follows it there;
    it used to score RC 0.667 for the partial off-road of its front wheels past the map's end."""
    entry = load_suite("adaptive").scenarios[0]
    assert entry.name == "a01_straight_free"
    log = drive(entry, KeepLanePolicy(), "adaptive")
    trace = log.agents["agent_0"]
    assert trace.left_map[-1] and not trace.left_map[:-1].any()
    assert not (trace.partial_off_road | trace.off_road).any()
    assert trace.x[-1] + 2.5 > 297.0  # it did get to the end of the road
    assert score_episode(log)["RC"] == 1.0


def test_running_a_red_light_is_recorded_and_costs_rc(tmp_path):
    path = tmp_path / "crossing.yaml"
    path.write_text(CROSSING)
    entry = load_suite(path).scenarios[0]
    careful = drive(entry, KeepLanePolicy(), "collaborative")
    blind = drive(entry, SignalBlind(), "collaborative")
    assert careful.signals == blind.signals == 16  # every connection of the 4 arms
    # The south approach is red while the west one is green: keep-lane stops, the blind one goes.
    assert not any(t.red_light.any() for t in careful.agents.values())
    assert not blind.agents["agent_0"].red_light.any()
    ran = blind.agents["agent_1"].red_light
    assert ran.sum() == 1  # once: on the row it entered the junction lane
    row = int(np.flatnonzero(ran)[0])
    colours = blind.scene.signals[int(np.searchsorted(blind.scene.time, blind.agents["agent_1"].time[row]))]
    assert 1 in colours.tolist()  # red somewhere at that moment (the south connections)
    costs = score_episode(blind)
    assert costs["cost.red_light"] == 0.5  # one of the two agents
    assert score_episode(careful)["cost.red_light"] == 0.0
