"""Lidar against hand-computed geometry on the straight two-lane road."""

import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role
from smarts.sensors.interface import AgentInterface, LidarInterface
from smarts.sensors.lidar import HIT_NONE, HIT_PEDESTRIAN, HIT_ROAD_EDGE, HIT_VEHICLE
from tests.sensors.support import (
    CAR_LENGTH,
    LANE0_Y,
    LANE1_Y,
    ROAD_LEFT_EDGE,
    ROAD_RIGHT_EDGE,
    observe,
    place,
    scene_env,
)

RAYS = 64
AHEAD, LEFT, BEHIND, RIGHT = 0, RAYS // 4, RAYS // 2, 3 * RAYS // 4
EDGE_TOLERANCE = 0.4  # the drivable raster's 0.25 m cells, filled where a cell touches the road


def _env(n_agents=3, **lidar):
    return scene_env(n_agents, AgentInterface(lidar=LidarInterface(rays=RAYS, range=30.0, **lidar)))


def test_rays_hit_the_nearest_box_and_the_road_edges_at_their_distances():
    env = _env()
    place(env, 0, 50.0, LANE0_Y)
    place(env, 1, 60.0, LANE0_Y)  # 10 m ahead: rear face at 7.7 m
    place(env, 2, 75.0, LANE0_Y)  # behind agent_1: never the first hit straight ahead
    obs = observe(env)
    dist, hit = obs["lidar"][0], obs["lidar_hit"][0]
    assert hit[AHEAD] == HIT_VEHICLE and dist[AHEAD] == pytest.approx(10.0 - CAR_LENGTH / 2, abs=1e-4)
    # Left: across lane 1 to the road's left edge; right: half a lane to the right edge.
    assert hit[LEFT] == HIT_ROAD_EDGE and dist[LEFT] == pytest.approx(ROAD_LEFT_EDGE - LANE0_Y, abs=EDGE_TOLERANCE)
    assert hit[RIGHT] == HIT_ROAD_EDGE and dist[RIGHT] == pytest.approx(LANE0_Y - ROAD_RIGHT_EDGE, abs=EDGE_TOLERANCE)
    # Behind, along the lane: nothing within 30 m (the road starts 50 m back).
    assert hit[BEHIND] == HIT_NONE and dist[BEHIND] == 30.0
    # A slanted ray reaches the left edge at (edge distance) / sin(angle).
    k = 3
    angle = 2 * math.pi * k / RAYS
    assert hit[k] == HIT_ROAD_EDGE
    assert dist[k] == pytest.approx((ROAD_LEFT_EDGE - LANE0_Y) / math.sin(angle), abs=EDGE_TOLERANCE / math.sin(angle))
    env.close()


def test_a_rotated_ego_sees_an_oblique_box_at_the_ray_box_intersection():
    env = _env()
    # Ego turned 10 degrees left in the middle of the road; a box 8 m ahead along its heading, turned
    # 90 degrees, so the straight-ahead ray meets its long side at 8 - width / 2.
    h = math.radians(10.0)  # the left edge is 3.2 / sin(10 deg) = 18 m ahead
    place(env, 0, 100.0, -3.2, h)
    place(env, 1, 100.0 + 8 * math.cos(h), -3.2 + 8 * math.sin(h), h + math.pi / 2)
    place(env, 2, 10.0, LANE0_Y)
    obs = observe(env)
    width = env.sim.table.width[env.sim.agent_row[1]]
    assert obs["lidar_hit"][0, AHEAD] == HIT_VEHICLE
    assert obs["lidar"][0, AHEAD] == pytest.approx(8.0 - width / 2, abs=1e-4)
    env.close()


def test_pedestrians_are_their_own_hit_type():
    env = _env()
    place(env, 0, 50.0, LANE0_Y)
    place(env, 1, 55.0, LANE0_Y, length=0.5, width=0.5)
    place(env, 2, 10.0, LANE0_Y)
    env.sim.table.role[env.sim.agent_row[1]] = int(Role.PEDESTRIAN)
    obs = observe(env)
    assert obs["lidar_hit"][0, AHEAD] == HIT_PEDESTRIAN
    assert obs["lidar"][0, AHEAD] == pytest.approx(4.75, abs=1e-4)
    env.close()


def test_an_ego_off_the_road_reports_the_edge_at_zero():
    env = _env()
    place(env, 0, 50.0, 5.0)  # 5 m north of the road
    obs = observe(env)
    assert obs["lidar_hit"][0, AHEAD] == HIT_ROAD_EDGE and obs["lidar"][0, AHEAD] == 0.0
    env.close()


def test_noise_is_seeded_and_leaves_rays_without_hits_at_the_range():
    def run(seed):
        env = _env(noise=0.2)
        env.reset(seed=seed)
        place(env, 0, 50.0, LANE0_Y)
        place(env, 1, 60.0, LANE1_Y)
        first = observe(env)
        env.step({a: np.zeros(3, dtype=np.float32) for a in env.agents})
        second = env.builder.build(env.sim, env.sim.active_agents)
        env.close()
        return first, second

    a1, a2 = run(3)
    b1, b2 = run(3)
    c1, _ = run(4)
    np.testing.assert_array_equal(a1["lidar"], b1["lidar"])
    np.testing.assert_array_equal(a2["lidar"], b2["lidar"])
    assert not np.array_equal(a1["lidar"], c1["lidar"])
    misses = a1["lidar_hit"][0] == HIT_NONE
    assert misses.any() and (a1["lidar"][0][misses] == 30.0).all()
    hits = ~misses
    assert (a1["lidar"][0][hits] >= 0).all() and (a1["lidar"][0][hits] <= 30.0).all()
