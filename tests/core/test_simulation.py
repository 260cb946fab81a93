"""The step loop on real built-in maps: entry, progress, events, goals, determinism, hand-over."""

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.core.provider import ProviderBase
from smarts.core.vehicle_table import Role
from smarts.env.assembly import build_simulation
from tests.builders import agent, make_spec

FORWARD = np.array([1.0, 0.0, 0.0])  # 10 m/s at dt 0.1


def _run(sim, steps, action=FORWARD):
    for _ in range(steps):
        sim.step({a: action for a in sim.agent_ids if sim.agent_active[sim.agent_index[a]]})
        sim.remove_done_agents()


def test_agent_enters_at_its_mission_start():
    sim = build_simulation(make_spec([agent(lane=1, offset=25.0, speed=7.0)]))
    sim.reset()
    row = sim.agent_row[0]
    lane = sim.road_map.lane("main_1")
    assert sim.table.lane[row] == lane
    assert sim.table.s[row] == pytest.approx(25.0, abs=1e-6)
    assert sim.table.speed[row] == 7.0
    assert abs(sim.table.t[row]) < 1e-6


def test_route_progress_follows_the_driven_distance():
    sim = build_simulation(make_spec([agent(offset=10.0)]))
    sim.reset()
    _run(sim, 20)
    assert sim.route_progress[0] == pytest.approx(20 * 1.0, abs=1e-6)  # from the mission start
    assert sim.route_progress_delta[0] == pytest.approx(1.0, abs=1e-6)


def test_driving_off_the_side_is_partial_then_full_off_road():
    sim = build_simulation(make_spec([agent(lane=1, offset=10.0)]))
    sim.reset()
    left = np.array([0.8, 0.05, 0.1])  # steer left: heading grows 0.1 rad per step
    seen = []
    for _ in range(40):
        sim.step({"agent_0": left})
        ev = sim.agent_events[0]
        seen.append((ev[Event.PARTIAL_OFF_ROAD], ev[Event.OFF_ROAD]))
        if sim.agent_done[0]:
            break
    partial_first = next(i for i, (p, _) in enumerate(seen) if p)
    off_first = next(i for i, (_, o) in enumerate(seen) if o)
    assert partial_first < off_first  # a corner leaves the road before the centre does
    assert sim.agent_done[0]  # off_road terminates by default


def test_collision_between_two_agents_ends_both():
    spec = make_spec([agent(lane=0, offset=10.0, speed=0.0), agent(lane=0, offset=30.0, speed=0.0)])
    sim = build_simulation(spec)
    sim.reset()
    hit = False
    for _ in range(30):
        sim.step({"agent_0": np.array([1.5, 0, 0]), "agent_1": np.array([0.0, 0, 0])})
        if sim.agent_events[:, Event.COLLISION].any():
            hit = True
            break
    assert hit and sim.agent_events[:, Event.COLLISION].all() and sim.agent_done.all()


def test_road_goal_is_reached_through_the_intersection():
    spec = make_spec(
        [agent("west_in", offset=60.0, speed=8.0, goal={"road": "north_out", "offset": 10.0})],
        map_name="intersection_4way_1lane",
    )
    sim = build_simulation(spec)
    sim.reset()
    ma = sim.mission_arrays
    for _ in range(400):
        # Follow the route path: aim two points ahead, limited by the controller.
        a = 0
        i = min(sim.route_index[a] + 2, ma.path_len[a] - 1)
        row = sim.agent_row[a]
        dx, dy = ma.paths[a, i, 0, 0] - sim.table.x[row], ma.paths[a, i, 0, 1] - sim.table.y[row]
        c, s = np.cos(sim.table.heading[row]), np.sin(sim.table.heading[row])
        local = np.array([c * dx + s * dy, -s * dx + c * dy])
        local *= min(0.8 / np.linalg.norm(local), 1.0)
        dh = np.arctan2(local[1], local[0])
        sim.step({"agent_0": np.array([local[0], local[1], dh])})
        if sim.agent_done[0]:
            break
    assert sim.agent_events[0, Event.REACHED_GOAL]
    assert not sim.agent_events[0, Event.OFF_ROAD]
    assert sim.road_map.road_ids[sim.road_map.lane_road[sim.table.lane[sim.agent_row[0]]]] == "north_out"


def test_max_steps_ends_the_episode():
    sim = build_simulation(make_spec([agent()], episode_steps=5))
    sim.reset()
    for k in range(5):
        sim.step({"agent_0": FORWARD})
    assert sim.agent_events[0, Event.MAX_STEPS] and sim.agent_done[0]


def _trajectory(spec, seed):
    sim = build_simulation(spec)
    sim.reset(seed=seed)
    out = []
    actions = {
        "agent_0": np.array([1.0, 0.05, 0.01]),
        "agent_1": np.array([0.6, 0.0, 0.02]),
    }
    for _ in range(40):
        sim.step({a: actions[a] for a in sim.agent_ids if sim.agent_active[sim.agent_index[a]]})
        rows = sim.table.alive_rows
        out.append(np.stack([sim.table.x[rows], sim.table.y[rows], sim.table.heading[rows], sim.table.speed[rows]]))
    sim.close()
    return out


def test_same_seed_gives_identical_trajectories():
    spec = make_spec([agent(lane=0), agent(lane=1, offset=40.0)])
    a, b = _trajectory(spec, 7), _trajectory(spec, 7)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_same_seed_identical_with_physics_vehicles():
    spec = make_spec([agent(lane=0, action_space="continuous"), agent(lane=1, offset=40.0)])

    def run():
        sim = build_simulation(spec)
        sim.reset(seed=3)
        states = []
        for _ in range(30):
            sim.step({"agent_0": np.array([0.5, 0.0, 0.1]), "agent_1": FORWARD})
            states.append(np.array([sim.table.x[:2], sim.table.y[:2], sim.table.heading[:2]]))
        sim.close()
        return np.array(states)

    first, second = run(), run()
    assert np.array_equal(first, second)
    assert first[-1, 1, 0] > first[0, 1, 0]  # steering left moved the physics car left (+y)


class HoldingProvider(ProviderBase):
    """A provider that keeps its vehicles where they are (stands in for parked traffic)."""

    name = "holding"

    def can_accept(self, sim, rows):
        return np.ones(len(rows), dtype=bool)

    def accept(self, sim, rows):
        sim.table.speed[rows] = 0.0


def test_hand_over_moves_a_row_between_providers_without_copying():
    sim = build_simulation(make_spec([agent()]))
    holder = HoldingProvider()
    sim.add_provider(holder)
    sim.reset()
    row = sim.agent_row[0]
    x = sim.table.x[row]
    sim.hand_over(np.array([row]), holder, Role.TRAFFIC)
    assert sim.table.owner[row] == holder.provider_id and sim.table.role[row] == Role.TRAFFIC
    assert sim.table.x[row] == x and sim.table.speed[row] == 0.0
    assert sim.table.ids[row] == "agent_0"
