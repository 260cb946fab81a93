"""Occlusion against hand-computed geometry: shadows of boxes seen from the ego's centre."""

import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role, VehicleTable
from smarts.sensors.interface import AgentInterface, OcclusionInterface
from smarts.sensors.observation import neighbour_feature_names
from smarts.sensors.occlusion import SHADOW_BINS, cast_shadows
from tests.sensors.support import CAR_WIDTH, LANE0_Y, LANE1_Y, observe, place, scene_env

BIN_DEG = 360.0 / SHADOW_BINS


def _scan(boxes, sensor_range=50.0):
    """Boxes (x, y, heading, length, width); row 0 is the ego. Returns visible fractions by row."""
    table = VehicleTable(16)
    for i, (x, y, h, length, width) in enumerate(boxes):
        table.add(f"v{i}", owner=0, role=Role.TRAFFIC, x=x, y=y, heading=h, length=length, width=width)
    rows = np.array([0])
    depth = np.empty((1, SHADOW_BINS))
    owner = np.empty((1, SHADOW_BINS), dtype=np.int64)
    visible = np.zeros((1, 16), dtype=np.float32)
    alive = table.alive_rows
    one = np.ones(1, dtype=np.int64)
    cast_shadows(table.data, alive, 0 * one, len(alive) * one, 0 * one, rows, sensor_range, depth, owner, visible)
    return visible[0], depth[0], owner[0]


def test_a_box_straight_behind_a_wider_one_is_hidden_and_the_nearer_one_fully_visible():
    ego = (0.0, 0.0, 0.0, 4.6, 1.9)
    blocker = (10.0, 0.0, 0.0, 4.6, 2.5)
    hidden = (20.0, 0.0, 0.0, 4.6, 1.9)
    visible, depth, owner = _scan([ego, blocker, hidden])
    assert visible[1] == 1.0
    assert visible[2] == 0.0
    # Straight ahead the nearest surface is the blocker's rear face at 10 - 2.3 m.
    ahead = SHADOW_BINS // 2
    assert owner[ahead] == 1 and depth[ahead] == pytest.approx(7.7, abs=1e-3)


def test_partly_covered_box_carries_the_uncovered_share_of_its_angular_extent():
    # Occluder spans y -1..1 at x 9.5..10.5; the target spans y 1..3 at x 19.5..20.5.
    ego = (0.0, 0.0, 0.0, 1.0, 1.0)
    occluder = (10.0, 0.0, 0.0, 1.0, 2.0)
    target = (20.0, 2.0, 0.0, 1.0, 2.0)
    visible, _, _ = _scan([ego, occluder, target])
    target_lo, target_hi = math.atan2(1.0, 20.5), math.atan2(3.0, 19.5)
    shadow_hi = math.atan2(1.0, 9.5)  # the occluder's upper near corner
    expected = (target_hi - shadow_hi) / (target_hi - target_lo)
    bin_share = math.radians(BIN_DEG) / (target_hi - target_lo)
    assert 0.3 < expected < 0.6
    assert visible[2] == pytest.approx(expected, abs=2 * bin_share)
    assert visible[1] == 1.0


def test_side_by_side_boxes_do_not_shadow_each_other_and_range_limits_sight():
    ego = (0.0, 0.0, 0.0, 4.6, 1.9)
    left = (10.0, 5.0, 0.0, 4.6, 1.9)
    right = (10.0, -5.0, 0.0, 4.6, 1.9)
    far = (60.0, 0.0, 0.0, 4.6, 1.9)
    straddling = (0.0, -30.0, math.pi / 2, 20.0, 2.0)  # its near end 20 m away, range 25 m
    visible, _, _ = _scan([ego, left, right, far, straddling], sensor_range=25.0)
    assert visible[1] == 1.0 and visible[2] == 1.0
    assert visible[3] == 0.0  # beyond the range
    assert visible[4] == 1.0  # the near face is in range along every ray


def test_a_small_far_box_narrower_than_a_bin_is_still_seen():
    ego = (0.0, 0.0, 0.0, 4.6, 1.9)
    pedestrian = (45.0, 3.0, 0.0, 0.1, 0.1)  # 0.13 degrees wide
    visible, _, _ = _scan([ego, pedestrian])
    assert visible[1] == 1.0


def test_rows_that_are_not_alive_read_zero_even_in_reused_buffers():
    """``visible`` is 0 for every row that is not alive, also where a buffer held an earlier scan."""
    table = VehicleTable(16)
    for i, x in enumerate((0.0, 10.0, -10.0)):
        table.add(f"v{i}", owner=0, role=Role.TRAFFIC, x=x, y=0.0, heading=0.0, length=4.6, width=1.9)
    rows = np.array([0])
    depth = np.empty((1, SHADOW_BINS))
    owner = np.empty((1, SHADOW_BINS), dtype=np.int64)
    visible = np.full((1, 16), 0.5, dtype=np.float32)  # stale values of an earlier scan
    one = np.ones(1, dtype=np.int64)
    for alive in (table.alive_rows, np.array([0, 2])):  # row 1 leaves between the scans
        cast_shadows(table.data, alive, 0 * one, len(alive) * one, 0 * one, rows, 50.0, depth, owner, visible)
    assert visible[0, 2] == 1.0
    assert (visible[0, [0, 1]] == 0.0).all() and (visible[0, 3:] == 0.0).all()


def test_hide_mode_drops_the_hidden_neighbour_and_flag_mode_reports_zero():
    for mode in ("hide", "flag"):
        env = scene_env(4, AgentInterface(occlusion=OcclusionInterface(enabled=True, mode=mode)))
        place(env, 0, 50.0, LANE0_Y)
        place(env, 1, 60.0, LANE0_Y)  # straight ahead: seen
        place(env, 2, 70.0, LANE0_Y)  # behind agent_1, same width: hidden
        place(env, 3, 60.0, LANE1_Y)  # ahead in the next lane: seen
        obs = observe(env)
        nb, mask = obs["neighbours"][0], obs["neighbour_mask"][0]
        col = neighbour_feature_names(env.builder.interface).index("visible_fraction")
        assert nb.shape[1] == col + 1 == 10
        present = nb[mask > 0]
        if mode == "hide":
            np.testing.assert_allclose(sorted(present[:, 1]), [0.0, LANE1_Y - LANE0_Y], atol=1e-4)
            np.testing.assert_allclose(present[:, 0], 10.0, atol=1e-4)
            np.testing.assert_array_equal(present[:, col], 1.0)
        else:
            assert len(present) == 3
            far = [r for r in present if round(float(r[0])) == 20]
            assert len(far) == 1 and far[0][col] == 0.0
            near = [r for r in present if round(float(r[0])) == 10]
            assert all(r[col] == 1.0 for r in near)
        env.close()


def test_occlusion_off_keeps_the_default_neighbour_shape_and_sees_through_vehicles():
    env = scene_env(3, AgentInterface())
    place(env, 0, 50.0, LANE0_Y)
    place(env, 1, 60.0, LANE0_Y)
    place(env, 2, 70.0, LANE0_Y)
    obs = observe(env)
    assert obs["neighbours"].shape == (1, 8, 9)
    assert obs["neighbour_mask"][0].sum() == 2
    assert CAR_WIDTH == pytest.approx(obs["neighbours"][0, 1, 7])
    env.close()
