"""Traffic, signals and pedestrians as the envs see them (real libsumo and the built-in model)."""

import numpy as np
import pytest

from smarts.core.vehicle_table import Role
from smarts.env import DrivingParallelEnv
from smarts.env.assembly import as_spec
from smarts.scenario import replace
from tests.builders import agent, make_spec
from zoo import make_policy

KEEP_LANE = make_policy("keep-lane")


def _drive(env, steps, obs):
    """Keep-lane actions for every live agent; returns the events seen per agent."""
    seen: dict[str, list] = {}
    for _ in range(steps):
        if not env.agents:
            break
        actions = {a: KEEP_LANE.act({k: v[None] for k, v in obs[a].items()})[0] for a in env.agents}
        obs, rewards, terms, truncs, infos = env.step(actions)
        for a, info in infos.items():
            seen.setdefault(a, []).extend(info.get("events", []))
    return obs, seen


def _roles(env):
    t = env.sim.table
    return np.bincount(t.role[t.alive_rows], minlength=len(Role))


@pytest.mark.parametrize(
    "scenario", ["intersection_4way_signal_traffic", "highway_merge_traffic", "t_junction_social", "straight_takeover"]
)
def test_library_traffic_scenarios_fill_the_road(scenario):
    env = DrivingParallelEnv(scenario)
    obs, _ = env.reset(seed=0)
    _drive(env, 60, obs)
    assert _roles(env)[Role.TRAFFIC] > 0
    env.close()


def test_same_seed_same_traffic_through_the_env():
    def run(seed):
        env = DrivingParallelEnv("intersection_4way_signal_traffic")
        obs, _ = env.reset(seed=seed)
        _drive(env, 80, obs)
        t = env.sim.table
        rows = t.alive_rows
        state = sorted((t.ids[r], round(t.x[r], 9), round(t.y[r], 9)) for r in rows)
        env.close()
        return state

    assert run(3) == run(3)


@pytest.mark.parametrize("engine", ["builtin", "sumo"])
def test_take_over_a_trip_and_hand_it_back_at_the_goal(engine):
    spec = as_spec("straight_takeover")
    spec = replace(spec, traffic=replace(spec.traffic, engine=engine, flows=[]))
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    sim = env.sim
    row = sim.agent_row[0]
    assert sim.table.ids[row] == "lead" and sim.table.role[row] == Role.AGENT
    assert sim.table.s[row] == pytest.approx(40.0, abs=0.5)  # the trip's departure position
    assert sim.table.lane[row] == sim.road_map.lane("main_1")
    obs, seen = _drive(env, 300, obs)
    assert "reached_goal" in seen["agent_0"]
    # The vehicle lives on as traffic, in the same row, driven by the traffic provider.
    assert sim.table.alive[row] and sim.table.ids[row] == "lead"
    assert sim.table.role[row] == Role.TRAFFIC and sim.table.owner[row] != sim.providers[0].provider_id
    x = sim.table.x[row]
    sim.step({})
    assert sim.table.x[row] > x  # still moving on its own
    env.close()


def test_a_pedestrian_walking_into_a_car_is_a_collision():
    spec = make_spec(
        [
            {
                "mission": {
                    "start": {"road": "south_in", "offset": 20.0, "speed": 0.0, "heading": 0.0},
                    "goal": {"endless": True},
                }
            }
        ],
        map_name="intersection_4way_1lane_peds",
        traffic={
            "engine": "sumo",
            "pedestrians": [{"id": "walker", "origin": "south_in", "destination": "north_out", "rate": 60}],
        },
        events={"terminate_on": ["collision"]},
    )
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    t, row = env.sim.table, env.sim.agent_row[0]
    for _ in range(300):  # move onto the sidewalk (pointing east) and wait for the walker
        obs, rewards, terms, truncs, infos = env.step(
            {"agent_0": np.array([0.2, 0, 0]) if t.x[row] < 4.5 else np.zeros(3)}
        )
        if terms["agent_0"]:
            break
    assert "collision" in infos["agent_0"]["events"]
    walkers = [r for r in t.alive_rows if t.role[r] == Role.PEDESTRIAN]
    assert walkers and abs(t.y[walkers[0]] - t.y[row]) < 2.0
    env.close()


def test_the_signal_ahead_is_in_the_observation():
    spec = make_spec(
        [agent("west_in", offset=20.0, speed=8.0, goal={"road": "east_out"})], map_name="intersection_4way_1lane_signal"
    )
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    signal = obs["agent_0"]["signal"]
    assert signal[:3].sum() == 1.0 and signal[2] == 1.0  # green for west-east at t = 0
    distance = signal[3]
    lane = env.sim.road_map.lane("west_in_0")
    assert distance == pytest.approx(env.sim.road_map.lane_length[lane] - 20.0, abs=1.0)
    for _ in range(480):  # stand still until the program turns the approach red
        obs, *_ = env.step({"agent_0": np.zeros(3)})
    assert obs["agent_0"]["signal"][0] == 1.0
