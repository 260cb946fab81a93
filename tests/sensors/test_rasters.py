"""Rasters and the RGB view against hand-computed pixels.

Rasters are 64 x 64 pixels of 0.5 m with the ego at the centre, heading up: pixel (row, col) has
its centre at ex = (32 - row - 0.5) * 0.5 m ahead and ey = (32 - col - 0.5) * 0.5 m to the left.
The ego stands at x = 50 on lane 0; agent_1 stands 6 m ahead (box ex 3.7..8.3, ey -0.95..0.95).
"""

import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role
from smarts.sensors.interface import AgentInterface, OcclusionInterface, RasterInterface
from smarts.sensors.rasters import (
    BACKGROUND,
    EGO,
    OCCLUSION_OCCLUDED,
    OCCLUSION_OUT_OF_RANGE,
    OCCLUSION_VISIBLE,
    ROAD,
    ROLE_BASE,
    SHADED_PALETTE,
    pixel_geometry,
)
from tests.sensors.support import LANE0_Y, observe, place, scene_env

LAYERS = ("drivable", "lanes", "route", "occupancy", "occlusion")


def _scene(mode="hide", heading=0.0, y=LANE0_Y):
    interface = AgentInterface(
        occlusion=OcclusionInterface(enabled=True, mode=mode, range=12.0),
        rasters=RasterInterface(size=64, resolution=0.5, layers=LAYERS, rgb=True),
    )
    env = scene_env(3, interface)
    place(env, 0, 50.0, y, heading)
    place(env, 1, 56.0, LANE0_Y)
    place(env, 2, 62.0, LANE0_Y)  # right behind agent_1 and as wide: hidden
    obs = observe(env)
    env.close()
    return {name: obs["rasters"][0, i] for i, name in enumerate(LAYERS)}, obs["rgb"][0]


def test_pixel_centres_follow_the_documented_frame():
    ex, ey, bins, dist = pixel_geometry(64, 0.5)
    q = 20 * 64 + 40
    assert ex[q] == pytest.approx((32 - 20 - 0.5) * 0.5) and ey[q] == pytest.approx((32 - 40 - 0.5) * 0.5)
    assert dist[q] == pytest.approx(math.hypot(ex[q], ey[q]))


def test_cells_under_a_vehicle_are_occupied_and_the_ego_is_not():
    layers, _ = _scene()
    occ = layers["occupancy"]
    assert occ[20, 31] == 1 and occ[20, 32] == 1  # 2 m behind agent_1's front, on its centre line
    assert occ[15, 30] == 1 and occ[24, 33] == 1  # its corners' pixels
    assert occ[20, 29] == 0 and occ[20, 34] == 0  # ey = +1.25 and -1.25: beside it
    assert occ[32, 32] == 0  # the ego itself
    assert occ[8, 32] == 0  # agent_2 is fully hidden: left out in hide mode
    flagged, _ = _scene(mode="flag")
    assert flagged["occupancy"][8, 32] == 1  # ... and drawn in flag mode (box ex 9.7..14.3)


def test_drivable_lanes_and_route_layers():
    layers, _ = _scene()
    drivable, lanes, route = layers["drivable"], layers["lanes"], layers["route"]
    # The road spans ey -1.6 .. 4.8 around lane 0's centre.
    assert drivable[32, 23] == 1 and drivable[32, 33] == 1  # ey 4.25 and -0.75
    assert drivable[32, 20] == 0 and drivable[32, 37] == 0  # ey 5.75 and -2.75
    # Lane 1's centre line is 3.2 m to the left: column 25 (ey 3.25); between the lanes there is none.
    assert lanes[0, 25] == 1 and lanes[40, 25] == 1
    assert lanes[0, 28] == 0
    # The route runs straight ahead along lane 0's centre (ey 0: the column right of the centre).
    assert route[:20, 32].all() and not route[:, 25].any()


def test_occlusion_layer_marks_shadow_range_and_visible_ground():
    layers, _ = _scene()
    occl = layers["occlusion"]
    assert occl[10, 32] == OCCLUSION_OCCLUDED  # 10.75 m ahead, behind agent_1's rear face at 3.7 m
    assert occl[0, 32] == OCCLUSION_OUT_OF_RANGE  # 15.75 m ahead, range 12 m
    assert occl[20, 20] == OCCLUSION_VISIBLE  # 8.1 m away at 45 degrees left, nothing in between
    assert occl[28, 32] == OCCLUSION_VISIBLE  # 1.75 m ahead, in front of agent_1


def test_the_view_rotates_with_the_ego():
    # Facing north from the middle of the road: the road runs across the image.
    layers, _ = _scene(heading=math.pi / 2, y=-3.2)
    drivable = layers["drivable"]
    assert drivable[32, 12] == 1 and drivable[32, 52] == 1  # 9.75 m west and east
    assert drivable[12, 32] == 0 and drivable[52, 32] == 0  # 9.75 m north and south: off the road


def test_rgb_paints_the_ego_the_others_the_road_and_the_shadows():
    _, rgb = _scene()
    visible = SHADED_PALETTE[OCCLUSION_VISIBLE]
    np.testing.assert_array_equal(rgb[32, 32], visible[EGO])
    np.testing.assert_array_equal(rgb[20, 31], visible[ROLE_BASE + int(Role.AGENT)])
    np.testing.assert_array_equal(rgb[28, 34], visible[ROAD])  # 1.75 m ahead, 1 m right
    np.testing.assert_array_equal(rgb[10, 33], SHADED_PALETTE[OCCLUSION_OCCLUDED][ROAD])
    np.testing.assert_array_equal(rgb[0, 33], SHADED_PALETTE[OCCLUSION_OUT_OF_RANGE][ROAD])
    np.testing.assert_array_equal(rgb[30, 14], visible[BACKGROUND])  # 8.8 m left, off the road
    assert rgb.dtype == np.uint8 and rgb.shape == (64, 64, 3)
