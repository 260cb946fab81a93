"""Scripted behaviour in the real simulator: a stopped car ahead, and an empty road."""

import numpy as np
import pytest

from smarts.env import DrivingParallelEnv
from smarts.sensors.interface import interface_from_dict
from tests.builders import agent, make_spec
from zoo.registry import make_policy


def drive(locator: str, agents: list[dict], steps: int, map_name: str = "straight_2lane"):
    """Drive agent_0 with the zoo policy; returns per-step (speed, accel, lateral offset, x of the
    nearest neighbour ahead) and the events seen."""
    policy = make_policy(locator)
    env = DrivingParallelEnv(make_spec(agents, map_name=map_name),
                             observation={"agent_0": interface_from_dict(policy.interface)})  # fmt: skip
    obs, _ = env.reset(seed=0)
    trace, events = [], []
    for _ in range(steps):
        if "agent_0" not in env.agents:
            break
        row = {k: v[None] for k, v in obs["agent_0"].items()}
        ego = row["ego"][0]
        trace.append((ego[0], ego[1], ego[7]))
        obs, _, _, _, infos = env.step({"agent_0": policy.act(row)[0]})
        events += infos.get("agent_0", {}).get("events", [])
    env.close()
    return np.array(trace), events


STOPPED_AHEAD = [agent(offset=20, speed=10, goal={"road": "main", "offset": 250}),
                 {**agent(offset=80, speed=0), "policy": "zoo:stand-still"}]  # fmt: skip


def test_tf_holds_behind_a_stopped_car():
    # both lanes blocked: with one free, TF's lane-change utility takes it and passes
    blocked = STOPPED_AHEAD + [{**agent(lane=1, offset=80, speed=0), "policy": "zoo:stand-still"}]
    trace, events = drive("zoo:tf-rules", blocked, 150)
    assert "collision" not in events
    assert trace[-30:, 0].max() < 0.05  # stopped, and it stays
    assert np.abs(trace[:, 2]).max() < 0.2  # in its lane


@pytest.mark.parametrize("locator", ["zoo:vcr-ttc", "zoo:vcr"])
def test_vcr_slows_to_a_stop_behind_a_stopped_car(locator):
    trace, events = drive(locator, STOPPED_AHEAD, 150)
    assert "collision" not in events
    assert trace[-20:, 0].max() < 0.05


# A car stopped across the lane (turned 90 deg): its corners lie just outside TF's alert box
# (corner-in-box, as the original), so the rules alone drive into it; the learned veto stops.
ACROSS_AHEAD = [STOPPED_AHEAD[0], {**agent(offset=80, speed=0), "policy": "zoo:stand-still"}]
ACROSS_AHEAD[1]["mission"]["start"]["heading"] = 1.62  # 93 deg: between 90 and 96 deg no corner is in the box


def test_tf_rules_alone_drive_into_a_car_across_the_lane():
    trace, events = drive("zoo:tf-rules", ACROSS_AHEAD, 100)
    assert "collision" in events and trace[-1, 0] > 10.0  # at speed


def test_tf_network_vetoes_before_a_car_across_the_lane():
    # The rules alone crash at step 43. Standing, ten stop votes open TF's 10-step anti-deadlock
    # window, in which the rules creep on (as the original's would drive on): it touches the car
    # after about 130 steps.
    trace, events = drive("zoo:tf", ACROSS_AHEAD, 100)
    assert "collision" not in events
    assert trace[:, 0].min() < 0.05  # it stood still short of the car


def test_aid_changes_lane_around_a_stopped_car():
    trace, events = drive("zoo:aid-cv", STOPPED_AHEAD, 250)
    assert "collision" not in events and "reached_goal" in events
    # it passed the stopped car in its lane (goal 170 m beyond it) by leaving the lane's centre
    assert np.abs(trace[:, 2]).max() > 1.0


def test_aid_brakes_when_every_lane_is_blocked():
    blocked = STOPPED_AHEAD + [{**agent(lane=1, offset=80, speed=0), "policy": "zoo:stand-still"}]
    trace, events = drive("zoo:aid-cv", blocked, 150)
    assert "collision" not in events
    assert trace[-20:, 0].max() < 0.5


# AID settles a little above the limit: its speed term (weight 0.5, relative error) is outweighed by
# the jerk of slowing down again after the cubic profiles overshoot.
@pytest.mark.parametrize("locator, cruise, tolerance", [
    ("zoo:tf-rules", 13.89, 0.02), ("zoo:tf", 13.89, 0.02), ("zoo:vcr-ttc", 11.0, 0.02), ("zoo:vcr", 11.0, 0.02),
    ("zoo:aid-cv", 13.89, 0.07),
])  # fmt: skip
def test_empty_road_reaches_cruise_speed_smoothly(locator, cruise, tolerance):
    trace, events = drive(locator, [agent(offset=20, speed=5)], 120)
    assert not set(events) & {"collision", "off_road", "off_route"}
    assert trace[-1, 0] == pytest.approx(cruise, rel=tolerance)
    assert np.abs(trace[:, 1]).max() <= 4.0 + 1e-3  # within the acceleration limit, no braking spikes
    assert np.diff(trace[:, 0]).min() > -0.3  # no slowing down on the way


@pytest.mark.parametrize("locator", ["zoo:tf-rules", "zoo:vcr-ttc", "zoo:aid-cv"])
def test_planner_drives_as_a_social_agent(locator):
    # Social agents observe through the scenario's interface (here the default one: 20 waypoints
    # 2 m apart), not the policy's; the planners read whatever spacing they are given.
    spec = make_spec([agent(offset=20, speed=8), {**agent(lane=1, offset=30, speed=8), "policy": locator}])
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    start = env.sim.table.x[env.sim.table.row_of["agent_1"]]
    for _ in range(50):
        obs, *_ = env.step({"agent_0": np.array([0.8, 0.0, 0.0], dtype=np.float32)})
    moved = env.sim.table.x[env.sim.table.row_of["agent_1"]] - start
    env.close()
    assert moved > 30.0  # about 5 s at 8 m/s or more
