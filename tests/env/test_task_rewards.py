"""Task rewards, term by term: each one is set up in the simulation and checked by hand."""

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.env import DrivingParallelEnv
from smarts.env.task_rewards import RewardWeights, TaskReward
from smarts.scenario import replace
from tests.builders import agent, make_spec

ONLY = dict(follow=0.0, travel=0.0, progress=0.0, goal=0.0, time=0.0, comfort=0.0, lane_centre=0.0,
            speeding=0.0, wrong_way=0.0, partial_off_road=0.0, collision=0.0, off_road=0.0)  # fmt: skip


def _weights(task="platoon", **on):
    return RewardWeights(task=task, **{**ONLY, **on})


def _platoon_env(follower_offset=10.0, lead_offset=30.0, speed=10.0, **weights):
    agents = [
        {"id": "follower", "mission": {"start": {"road": "main", "offset": follower_offset, "speed": speed},
                                       "goal": {"endless": True}, "follow": "lead"}},
        {"id": "lead", "mission": {"start": {"road": "main", "offset": lead_offset, "speed": speed},
                                   "goal": {"endless": True}}},
    ]  # fmt: skip
    env = DrivingParallelEnv(make_spec(agents, map_name="straight_2lane"), reward=TaskReward(_weights(**weights)))
    env.reset(seed=0)
    return env


def _step(env, follower=(1.0, 0.0, 0.0), lead=(1.0, 0.0, 0.0)):
    actions = {"follower": np.array(follower), "lead": np.array(lead)}
    return env.step({a: actions[a] for a in env.agents})[1]


def test_follow_term_peaks_just_beyond_the_follow_margin():
    env = _platoon_env(follow=1.0, target_gap=0.5)
    rewards = _step(env)  # both drive 1 m: the gap stays 20 m bumper to bumper minus lengths
    sim = env.sim
    gap = 20.0 - sim.table.length[sim.agent_row[0]]
    speed = sim.table.speed[sim.agent_row[0]]
    margin = 2.5 + 1.0 * speed
    time_gap = (gap - margin) / speed
    assert rewards["follower"] == pytest.approx(1.0 - abs(time_gap - 0.5) / 3.0, abs=1e-6)
    assert rewards["lead"] == 0.0  # the lead follows nobody


def test_inside_the_margin_following_pays_nothing():
    env = _platoon_env(lead_offset=15.0, follow=1.0)
    assert _step(env)["follower"] == 0.0  # 5 m centre to centre: inside 2.5 m + 1 s * 10 m/s


def test_a_lost_lead_pays_nothing_but_travel_still_pays():
    env = _platoon_env(lead_offset=90.0, follow=1.0, travel=0.5)
    rewards = _step(env)
    assert rewards["follower"] == pytest.approx(0.5 * env.sim.table.speed[env.sim.agent_row[0]] * env.sim.dt)


def test_collision_penalty_is_charged_on_the_collision_step():
    env = _platoon_env(lead_offset=14.0, speed=10.0, collision=7.0)
    for _ in range(10):
        rewards = _step(env, follower=(1.5, 0.0, 0.0), lead=(0.5, 0.0, 0.0))
        if env.sim.agent_events[0, Event.COLLISION]:
            break
    assert env.sim.agent_events[0, Event.COLLISION]
    assert rewards["follower"] == pytest.approx(-7.0)


def _single(action_space="relative_target_pose", **kw):
    spec = make_spec([agent(offset=10.0, speed=10.0, action_space=action_space, **kw)], map_name="straight_2lane")
    return spec


def test_comfort_term_pays_steps_within_every_comfort_limit():
    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(comfort=2.0)))
    env.reset(seed=0)
    assert env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"] == 2.0  # steady 10 m/s
    # +1.5 m/s in one step: 15 m/s^2 acceleration (the limiter allows 4) -> uncomfortable.
    assert env.step({"agent_0": np.array([1.15, 0.0, 0.0])})[1]["agent_0"] == 0.0


def test_lane_centre_and_speeding_terms():
    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(lane_centre=1.0)))
    env.reset(seed=0)
    env.step({"agent_0": np.array([1.0, 0.0, 0.0])})
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    assert r == 1.0  # on the lane centre
    row = env.sim.agent_row[0]
    env.sim.table.y[row] += 0.8  # 0.8 m left of the lane centre
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    width = env.sim.road_map.lane_width[env.sim.table.lane[row]]
    assert r == pytest.approx(1.0 - 0.8 / (0.5 * width), abs=1e-3)

    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(speeding=1.0)))
    env.reset(seed=0)
    limit = env.sim.road_map.lane_speed_limit[env.sim.table.lane[env.sim.agent_row[0]]]
    for _ in range(30):  # accelerate past the limit
        r = env.step({"agent_0": np.array([2.2, 0.0, 0.0])})[1]["agent_0"]
    v = env.sim.table.speed[env.sim.agent_row[0]]
    assert v > limit and r == pytest.approx(-min((v - limit) / (0.5 * limit), 1.0))


def test_drive_terms_progress_time_and_goal():
    spec = make_spec([agent(offset=80.0, speed=10.0, goal={"road": "main", "offset": 95.0})], map_name="straight_2lane")
    env = DrivingParallelEnv(spec, reward=TaskReward(_weights("drive", progress=0.5, time=0.25)))
    env.reset(seed=0)
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    assert r == pytest.approx(0.5 * 1.0 - 0.25, abs=1e-6)
    env = DrivingParallelEnv(spec, reward=TaskReward(_weights("drive", goal=3.0)))
    env.reset(seed=0)
    for _ in range(40):
        _, rewards, terms, _, _ = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})
        if terms.get("agent_0"):
            break
    assert env.sim.agent_events[0, Event.REACHED_GOAL] and rewards["agent_0"] == pytest.approx(3.0)


def test_weights_are_validated():
    with pytest.raises(ValueError, match="reward.task"):
        RewardWeights(task="race")
    with pytest.raises(ValueError, match="reward.collision"):
        RewardWeights(collision=-1.0)


@pytest.mark.parametrize("task", ["platoon", "drive"])
def test_event_penalties_wrong_way_partial_and_full_off_road(task):
    """Each road-conduct penalty alone, in both task rewards, on the step its event fires."""
    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(task, partial_off_road=2.0)))
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    width = env.sim.road_map.lane_width[env.sim.table.lane[row]]
    # Right lane of two: its centre is half a lane from the road's right edge. The car's centre goes
    # 0.1 m inside that edge, so its right corners (half a car width further) are off the surface.
    env.sim.table.y[row] -= 0.5 * width - 0.1
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    ev = env.sim.agent_events[0]
    assert ev[Event.PARTIAL_OFF_ROAD] and not ev[Event.OFF_ROAD]
    assert r == pytest.approx(-2.0)

    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(task, off_road=3.0)))
    env.reset(seed=0)
    env.sim.table.y[env.sim.agent_row[0]] += 30.0
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    assert env.sim.agent_events[0, Event.OFF_ROAD] and r == pytest.approx(-3.0)

    env = DrivingParallelEnv(_single(), reward=TaskReward(_weights(task, wrong_way=1.5)))
    env.reset(seed=0)
    assert env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"] == 0.0
    env.sim.table.heading[env.sim.agent_row[0]] += np.pi  # turned around in its lane
    r = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})[1]["agent_0"]
    assert env.sim.agent_events[0, Event.WRONG_WAY] and r == pytest.approx(-1.5)


def test_red_light_term_charges_the_step_the_benchmark_records_as_running_a_red_light(tmp_path):
    """The crossing of the benchmark's red-light test: the signal-blind driver of the south arm
    enters the junction on red once; the term charges exactly that step (the recorder's rule),
    the west driver (green) nothing."""

    from smarts.benchmark.recorder import EpisodeRecorder
    from smarts.benchmark.suites import load_suite
    from tests.benchmark.test_rules import CROSSING, SignalBlind

    path = tmp_path / "crossing.yaml"
    path.write_text(CROSSING)
    entry = load_suite(path).scenarios[0]
    spec = replace(entry.spec, agents=[replace(a, action_space="relative_target_pose")
                                                   for a in entry.spec.agents])  # fmt: skip
    env = DrivingParallelEnv(spec, reward=TaskReward(_weights("drive", red_light=3.0)))
    obs, _ = env.reset(seed=0)
    recorder = EpisodeRecorder(env.sim, env.possible_agents, scenario=entry.name, task="collaborative", episode=0,
                               seed=0, time_limit=entry.time_limit, follow=entry.follow)  # fmt: skip
    env.add_step_listener(lambda sim: recorder.record())
    policy, charged = SignalBlind(), {a: [] for a in env.possible_agents}
    try:
        while env.agents and env.sim.time < entry.time_limit - 1e-9:
            batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
            obs, rewards, *_ = env.step(dict(zip(env.agents, policy.act(batch))))
            for a in env.possible_agents:
                charged[a].append(-rewards.get(a, 0.0))
        log = recorder.finish()
    finally:
        env.close()
    ran = log.agents["agent_1"].red_light
    assert ran.sum() == 1 and not log.agents["agent_0"].red_light.any()
    south = np.array(charged["agent_1"])
    assert np.flatnonzero(south).tolist() == np.flatnonzero(ran).tolist() and south[ran][0] == pytest.approx(3.0)
    assert not np.any(charged["agent_0"])
