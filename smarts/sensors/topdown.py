"""A top-down RGB view of the whole map: road surface, lane centre lines, vehicles, goals.

The map layer is drawn once per map and reused; each frame only draws the vehicles, so ``render()``
stays cheap enough to record videos.
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

from smarts.core.missions import GOAL_NONE
from smarts.core.simulation import Simulation
from smarts.core.vehicle_table import Role
from smarts.maps import RoadMap

BACKGROUND = (34, 102, 51)
ROAD = (70, 70, 74)
LANE_LINE = (150, 150, 150)
ROLE_COLOURS = {
    int(Role.AGENT): (230, 60, 50),
    int(Role.SOCIAL_AGENT): (240, 160, 40),
    int(Role.TRAFFIC): (70, 130, 230),
    int(Role.REPLAY): (160, 90, 220),
    int(Role.PEDESTRIAN): (250, 250, 250),
}


class TopDownRenderer:
    def __init__(self, road_map: RoadMap, max_size: int = 800, margin: float = 5.0):
        self.road_map = road_map
        xmin, ymin, xmax, ymax = road_map.bounds
        self.origin = np.array([xmin - margin, ymin - margin])
        extent = max(xmax - xmin, ymax - ymin) + 2 * margin
        self.scale = max_size / extent  # pixels per metre
        self.width = max(int(np.ceil((xmax - xmin + 2 * margin) * self.scale)), 1)
        self.height = max(int(np.ceil((ymax - ymin + 2 * margin) * self.scale)), 1)
        self._map_layer = self._draw_map()

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Map metres to pixel coordinates (y grows downwards in images)."""
        px = (xy[..., 0] - self.origin[0]) * self.scale
        py = self.height - (xy[..., 1] - self.origin[1]) * self.scale
        return np.stack([px, py], axis=-1)

    def _draw_map(self) -> Image.Image:
        rm = self.road_map
        image = Image.new("RGB", (self.width, self.height), BACKGROUND)
        # Road surface from the drivable raster, resampled to the view.
        h, w = rm.drivable.shape
        ys = (self.height - (np.arange(self.height) + 0.5)) / self.scale + self.origin[1]
        xs = (np.arange(self.width) + 0.5) / self.scale + self.origin[0]
        iy = np.floor((ys - rm.raster_origin[1]) / rm.raster_resolution).astype(np.int64)
        ix = np.floor((xs - rm.raster_origin[0]) / rm.raster_resolution).astype(np.int64)
        valid_y = (iy >= 0) & (iy < h)
        valid_x = (ix >= 0) & (ix < w)
        surface = np.zeros((self.height, self.width), dtype=bool)
        surface[np.ix_(valid_y, valid_x)] = rm.drivable[np.ix_(iy[valid_y], ix[valid_x])]
        pixels = np.asarray(image).copy()
        pixels[surface] = ROAD
        image = Image.fromarray(pixels)
        draw = ImageDraw.Draw(image)
        for lane in range(rm.num_lanes):
            if rm.lane_internal[lane]:
                continue
            pts = self.to_pixels(rm.lane_polyline(lane))
            draw.line([tuple(p) for p in pts], fill=LANE_LINE, width=1)
        return image

    def render(self, sim: Simulation) -> np.ndarray:
        image = self._map_layer.copy()
        draw = ImageDraw.Draw(image)
        ma = sim.mission_arrays
        for a in sim.active_agents:
            if ma.goal_kind[a] != GOAL_NONE:
                gx, gy = self.to_pixels(ma.goal_xy[a])
                r = max(ma.goal_radius[a] * self.scale, 2.0)
                draw.ellipse([gx - r, gy - r, gx + r, gy + r], outline=(255, 220, 0), width=2)
        table = sim.table
        rows = table.alive_rows
        if rows.size:
            polygons = self.to_pixels(table.corners(rows))
            for row, poly in zip(rows, polygons):
                colour = ROLE_COLOURS.get(int(table.role[row]), (200, 200, 200))
                draw.polygon([tuple(p) for p in poly], fill=colour, outline=(0, 0, 0))
                front = poly[:2].mean(axis=0)
                centre = poly.mean(axis=0)
                draw.line([tuple(centre), tuple(front)], fill=(0, 0, 0), width=1)
        return np.asarray(image)
