"""Ego-centred rasters and the RGB top-down view composed from them.

Each raster is ``size`` x ``size`` pixels of ``resolution`` metres, centred on the ego's centre and
rotated to its heading: row 0 is ahead, column 0 is to the left (the ego drives up the image).
Layers (uint8 [L, size, size], in the interface's order):
- ``drivable``: 1 on the road surface (the map's drivable raster);
- ``lanes``: 1 within half a pixel of a lane centre line (junction-internal lanes left out);
- ``route``: 1 on the ego's route path;
- ``occupancy``: 1 under another road user's box (vehicles and pedestrians, not the ego; with
  occlusion in ``hide`` mode, fully hidden ones are left out);
- ``occlusion``: 2 visible, 1 occluded (in a box's shadow), 0 beyond the occlusion range.
``rgb`` (uint8 [size, size, 3]) paints them: grass, grey road, light lane lines, the route, other
road users by role, the ego in red, and shades occluded and out-of-range ground.

Every output pixel is sampled by inverse mapping to map coordinates (one lookup in the map's
``raster_codes``, which hold on-road and on-a-lane-line in one byte, and one comparison with the
occlusion depth buffer, whose per-pixel bin and distance are fixed in the ego frame and
precomputed); boxes and the route are drawn forward into the few pixels they cover.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import gymnasium as gym
import numba
import numpy as np

from smarts.compiled import njit
from smarts.core.simulation import Scope, Simulation
from smarts.core.vehicle_table import COLUMN
from smarts.sensors.interface import RASTER_LAYERS, RasterInterface
from smarts.sensors.map_fields import ON_ROAD, cell_grid, map_fields, raster_codes
from smarts.sensors.occlusion import SHADOW_BINS, Shadows
from smarts.sensors.rays import parallel_worth_it

OCCLUSION_OUT_OF_RANGE, OCCLUSION_OCCLUDED, OCCLUSION_VISIBLE = 0, 1, 2

# Palette rows: the scene, then one colour per ``Role`` value (index ROLE_BASE + role).
BACKGROUND, ROAD, LANE, ROUTE, EGO = 0, 1, 2, 3, 4
ROLE_BASE = 5
PALETTE = np.array(
    [
        (34, 102, 51),  # background
        (88, 88, 92),  # road
        (190, 190, 190),  # lane centre lines
        (60, 190, 230),  # route
        (230, 50, 40),  # ego
        (200, 200, 200),  # Role.NONE
        (250, 140, 150),  # Role.AGENT (another learner)
        (240, 160, 40),  # Role.SOCIAL_AGENT
        (70, 120, 235),  # Role.TRAFFIC
        (160, 90, 220),  # Role.REPLAY
        (250, 250, 250),  # Role.PEDESTRIAN
    ],
    dtype=np.uint8,
)
OCCLUDED_SHADE = 0.55
OUT_OF_RANGE_SHADE = 0.3
SHADED_PALETTE = np.stack([(PALETTE * f).astype(np.uint8) for f in (OUT_OF_RANGE_SHADE, OCCLUDED_SHADE, 1.0)])
"""The palette per occlusion value (out of range, occluded, visible)."""
_ROUTE_BACK = 400  # route points searched behind the ego's nearest one
_ROUTE_AHEAD = 200  # ... and at most this many beyond the view's diameter ahead of it


def pixel_geometry(size: int, resolution: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ego-frame centre (x ahead, y left), depth-buffer bin and distance of every pixel, row-major."""
    centre = (size / 2.0 - np.arange(size) - 0.5) * resolution
    ex = np.repeat(centre, size)  # row -> ahead
    ey = np.tile(centre, size)  # column -> left
    angle = np.arctan2(ey, ex)
    bins = np.floor((angle + np.pi) / (2 * np.pi / SHADOW_BINS)).astype(np.int64) % SHADOW_BINS
    return ex, ey, bins, np.hypot(ex, ey)


class RasterSensor:
    """``rasters`` and ``rgb`` for the agents of one interface group; the per-pixel geometry and
    scratch buffers are made once and reused every step."""

    def __init__(self, config: RasterInterface, hide_hidden: bool = False):
        self.config = config
        self.hide_hidden = hide_hidden
        s = config.size
        self._ex, self._ey, self._bin, self._dist = pixel_geometry(s, config.resolution)
        self._slot = np.full(len(RASTER_LAYERS), -1, dtype=np.int64)
        for i, name in enumerate(config.layers):
            self._slot[RASTER_LAYERS.index(name)] = i
        self._pixels = RasterPixels(
            self._ex, self._ey, self._bin, self._dist, int(s), float(config.resolution), self._slot
        )
        self._no_shadow = np.zeros((1, 1))
        self._no_visible = np.zeros((1, 1), dtype=np.float32)

    def spaces(self) -> dict[str, gym.spaces.Box]:
        s, layers = self.config.size, len(self.config.layers)
        out = {}
        if layers:
            out["rasters"] = gym.spaces.Box(0, OCCLUSION_VISIBLE, (layers, s, s), np.uint8)
        if self.config.rgb:
            out["rgb"] = gym.spaces.Box(0, 255, (s, s, 3), np.uint8)
        return out

    def observe(
        self, sim: Simulation, agents: np.ndarray, rows: np.ndarray, shadows: Shadows | None
    ) -> dict[str, np.ndarray]:
        cfg = self.config
        n, s = rows.shape[0], cfg.size
        layers = np.empty((n, len(cfg.layers), s, s), dtype=np.uint8)
        rgb = np.empty((n, s, s, 3) if cfg.rgb else (1, s, s, 3), dtype=np.uint8)  # (a dummy without rgb)
        scope = sim.scope(agents)
        for m, idx in _by_map(sim, agents):
            part = slice(None) if idx is None else idx
            out_layers = layers if idx is None else np.empty((len(idx), *layers.shape[1:]), dtype=np.uint8)
            out_rgb = rgb if idx is None or not cfg.rgb else np.empty((len(idx), s, s, 3), dtype=np.uint8)
            self._draw(sim, sim.map_stack.maps[m], agents[part], rows[part], scope, part, shadows, out_layers, out_rgb)
            if idx is not None:
                layers[idx] = out_layers
                if cfg.rgb:
                    rgb[idx] = out_rgb
        out = {}
        if cfg.layers:
            out["rasters"] = layers
        if cfg.rgb:
            out["rgb"] = rgb
        return out

    def _draw(self, sim, road_map, agents, rows, scope, part, shadows, layers, rgb) -> None:
        """Draw the agents on one map (the map's own fields: every agent here drives on it)."""
        cfg = self.config
        f = map_fields(road_map)
        ma = sim.mission_arrays
        # A pixel is on a lane line within half a pixel of it (at least one map cell).
        lane_cells = max(0.5 * cfg.resolution * f.inv_res, 1.0)
        grid = cell_grid(f, raster_codes(road_map, lane_cells))  # on road / on a lane line per cell
        paths = RoutePaths(ma.flat_paths, ma.flat_valid, int(ma.stride), ma.path_len, sim.route_index)
        sh = ShadowView(
            shadows.depth[part] if shadows is not None else self._no_shadow,
            shadows.visible[part] if shadows is not None else self._no_visible,
            float(shadows.range) if shadows is not None else math.inf,
            shadows is not None, self.hide_hidden and shadows is not None,
        )  # fmt: skip
        sub = Scope(scope.alive, scope.lo[part], scope.hi[part], scope.base[part])
        kernel = draw_rasters_parallel if parallel_worth_it(len(rows)) else draw_rasters
        kernel(sim.table.data, sim.table.role, sub, agents, rows, self._pixels, grid, paths, sh,
               RasterOut(layers, cfg.rgb, rgb))  # fmt: skip


def _by_map(sim: Simulation, agents: np.ndarray):
    """``(map number, agent positions)`` per map the agents drive on; positions None when they all
    drive on one map (the usual case: no gathering)."""
    maps = sim.episode_map[sim.agent_episode[agents]]
    if sim.map_stack.num_maps == 1 or len(maps) == 0 or (maps == maps[0]).all():
        return [(int(maps[0]) if len(maps) else 0, None)]
    return [(int(m), np.flatnonzero(maps == m)) for m in np.unique(maps).tolist()]


class RasterPixels(NamedTuple):
    """The per-pixel geometry of a raster sensor (made once): pixel centres in the ego frame
    (``ex``, ``ey``, metres), each pixel's shadow bin and distance, the size, metres per pixel,
    and where each layer goes (``slot``, -1: not drawn)."""

    ex: np.ndarray
    ey: np.ndarray
    bin: np.ndarray
    dist: np.ndarray
    size: int
    res: float
    slot: np.ndarray


class RoutePaths(NamedTuple):
    """Every agent's route path (``MissionArrays``) and where along it each agent is."""

    flat_paths: np.ndarray
    flat_valid: np.ndarray
    stride: int
    path_len: np.ndarray
    route_index: np.ndarray


class RasterOut(NamedTuple):
    """Where the raster kernel draws: ``layers`` uint8[n, L, size, size] and, when ``want_rgb``,
    ``rgb`` uint8[n, size, size, 3] (else a one-image dummy)."""

    layers: np.ndarray
    want_rgb: bool
    rgb: np.ndarray


class ShadowView(NamedTuple):
    """Shadows for the raster kernel: per agent depth buffers and visible fractions (dummies when
    ``have_shadows`` is False), the sensor range, and whether hidden road users are left out."""

    depth: np.ndarray
    visible: np.ndarray
    sensor_range: float
    have_shadows: bool
    hide_hidden: bool


@njit(nogil=True)
def draw_rasters(data, role, scope, agents, rows, pix, grid, paths, sh, out):  # pragma: no cover - compiled
    """Draw the layers (and the RGB view) of each agent ``agents[i]`` (row ``rows[i]``) among its
    episode's road users (``scope``, a ``smarts.core.simulation.Scope``) into ``out``."""
    scratch = _new_scratch(pix.size * pix.size)
    for i in range(rows.shape[0]):
        _draw_one(data, role, scope, i, agents[i], rows[i], pix, grid, paths, sh, scratch, out)


@njit(nogil=True, parallel=True)
def draw_rasters_parallel(data, role, scope, agents, rows, pix, grid, paths, sh, out):  # pragma: no cover - compiled
    """``draw_rasters`` with the agents spread over threads (each its own scratch buffers)."""
    for i in numba.prange(rows.shape[0]):
        _draw_one(
            data, role, scope, i, agents[i], rows[i], pix, grid, paths, sh, _new_scratch(pix.size * pix.size), out
        )


class _Scratch(NamedTuple):
    """One agent's per-pixel working planes: who covers the pixel (``_draw_boxes``), the route,
    the map cell, its ``raster_codes`` byte and the occlusion level."""

    occupant: np.ndarray
    route: np.ndarray
    cell: np.ndarray
    code: np.ndarray
    shade: np.ndarray


@njit(nogil=True, inline="always")
def _new_scratch(n_px):  # pragma: no cover - compiled
    return _Scratch(
        np.empty(n_px, np.int32), np.empty(n_px, np.uint8), np.empty(n_px, np.int32), np.empty(n_px, np.uint8),
        np.empty(n_px, np.uint8),
    )  # fmt: skip


@njit(nogil=True, inline="always")
def _agent_part(a, i):  # pragma: no cover - compiled
    """Row ``i`` of a per-agent array, or the dummy's only row."""
    return a[min(np.int64(i), np.int64(a.shape[0] - 1))]  # (a prange index is unsigned)


@njit(nogil=True)
def _draw_one(data, role, scope, i, a, r, pix, grid, paths, sh, scratch, out):  # pragma: no cover - compiled
    """Agent ``a`` (row ``r``, number ``i`` of the call): its rasters into its planes of ``out``,
    with its own scratch planes."""
    size, res = pix.size, pix.res
    half = 0.5 * size * res
    view = half * math.sqrt(2.0)  # farthest pixel corner from the ego
    x, y, h = data[_X, r], data[_Y, r], data[_H, r]
    c, s = math.cos(h), math.sin(h)
    occupant, route = scratch.occupant, scratch.route
    alive = scope.alive[scope.lo[i] : scope.hi[i]]
    _draw_boxes(data, alive, scope.base[i], r, (x, y, h, c, s), half, pix, sh, _agent_part(sh.visible, i), occupant)
    _draw_route(paths, a, x, y, c, s, half, view, pix, route)
    _read_map(grid, pix, sh, _agent_part(sh.depth, i), x, y, c, s, scratch.cell, scratch.code, scratch.shade)
    _fill_layers(pix, out.layers[i], scratch.code, route, occupant, scratch.shade)
    if out.want_rgb:
        _compose_rgb(size * size, role, occupant, route, scratch.code, scratch.shade, _agent_part(out.rgb, i))


# The layers of ``_draw_one``, one loop nest each, inlined into it by numba.
@njit(nogil=True, inline="always")
def _draw_boxes(data, alive, row_base, r, ego, half, pix, sh, visible, occupant):  # pragma: no cover - compiled
    """Boxes: ego = -1, other road users = row + 1, into the pixels whose centre they cover
    (``ego``: the ego's x, y, heading and the heading's cosine and sine)."""
    px_ex, px_ey, size, res = pix.ex, pix.ey, pix.size, pix.res
    x, y, h, c, s = ego
    occupant[:] = 0
    for j in alive:
        if j != r and sh.hide_hidden and visible[j - row_base] <= 0.0:
            continue
        dx, dy = data[_X, j] - x, data[_Y, j] - y
        bx, by = c * dx + s * dy, -s * dx + c * dy
        hl, hw = 0.5 * data[_LENGTH, j], 0.5 * data[_WIDTH, j]
        reach = math.hypot(hl, hw)
        if abs(bx) - reach > half or abs(by) - reach > half:
            continue
        rel = data[_H, j] - h
        rc, rs = math.cos(rel), math.sin(rel)
        row0 = max(int(math.floor(0.5 * size - (bx + reach) / res)), 0)
        row1 = min(int(math.floor(0.5 * size - (bx - reach) / res)), size - 1)
        col0 = max(int(math.floor(0.5 * size - (by + reach) / res)), 0)
        col1 = min(int(math.floor(0.5 * size - (by - reach) / res)), size - 1)
        mark = -1 if j == r else j + 1
        for pr in range(row0, row1 + 1):
            for pc in range(col0, col1 + 1):
                q = pr * size + pc
                qx, qy = px_ex[q] - bx, px_ey[q] - by
                if abs(rc * qx + rs * qy) <= hl and abs(-rs * qx + rc * qy) <= hw:
                    if j == r or occupant[q] <= 0:
                        occupant[q] = mark


@njit(nogil=True, inline="always")
def _draw_route(paths, a, x, y, c, s, half, view, pix, route):  # pragma: no cover - compiled
    """Route: agent ``a``'s path polyline sampled every half pixel, from where it enters the view;
    a segment with both ends a pixel beyond the same side of the image (``half`` metres from the
    centre) has no sample in it and is skipped."""
    size, res = pix.size, pix.res
    flat_paths, flat_valid, stride, path_len, route_index = (
        paths.flat_paths,
        paths.flat_valid,
        paths.stride,
        paths.path_len,
        paths.route_index,
    )
    route[:] = 0
    base = a * stride
    k0 = route_index[a]
    while k0 > 0 and route_index[a] - k0 < _ROUTE_BACK:
        p = flat_paths[base + k0 - 1, 0]
        if math.hypot(p[0] - x, p[1] - y) > view + 2.0:
            break
        k0 -= 1
    px_prev, py_prev = 0.0, 0.0
    entered = False
    last = min(path_len[a], route_index[a] + int(2.0 * view) + _ROUTE_AHEAD)  # ~1 m per point
    for k in range(k0, last):
        if not flat_valid[base + k, 0]:
            break
        p = flat_paths[base + k, 0]
        dx, dy = p[0] - x, p[1] - y
        ex, ey = c * dx + s * dy, -s * dx + c * dy
        edge = half + res
        beyond = (
            (ex > edge and px_prev > edge) or (ex < -edge and px_prev < -edge)
            or (ey > edge and py_prev > edge) or (ey < -edge and py_prev < -edge)
        )  # fmt: skip
        if k > k0 and not beyond:
            seg = math.hypot(ex - px_prev, ey - py_prev)
            n_sub = max(int(math.ceil(seg / (0.5 * res))), 1)
            for u in range(n_sub + 1):
                f = u / n_sub
                qx, qy = px_prev + (ex - px_prev) * f, py_prev + (ey - py_prev) * f
                pr = int(math.floor(0.5 * size - qx / res))
                pc = int(math.floor(0.5 * size - qy / res))
                if 0 <= pr < size and 0 <= pc < size:
                    route[pr * size + pc] = 1
        px_prev, py_prev = ex, ey
        near = math.hypot(ex, ey) <= view + 2.0
        if entered and not near and k > route_index[a]:
            break
        entered = entered or near


@njit(nogil=True, inline="always")
def _read_map(grid, pix, sh, depth, x, y, c, s, cell, code, shade):  # pragma: no cover - compiled
    """Every pixel: its map cell, that cell's code, and the pixel's shadow level. Simple loops
    over the flat pixel index with 32-bit cell numbers, so the compiler vectorises them."""
    px_ex, px_ey, px_bin, px_dist = pix.ex, pix.ey, pix.bin, pix.dist
    ox, oy, inv_res = grid.origin[0], grid.origin[1], grid.inv_res
    mx, my, width, codes = grid.cell_max[0], grid.cell_max[1], np.int32(grid.width), grid.cells
    n_px = pix.size * pix.size
    for q in range(n_px):
        ex, ey = px_ex[q], px_ey[q]
        cx = min(max((x + c * ex - s * ey - ox) * inv_res, 0.0), mx)
        cy = min(max((y + s * ex + c * ey - oy) * inv_res, 0.0), my)
        cell[q] = np.int32(cy) * width + np.int32(cx)
    for q in range(n_px):
        code[q] = codes[cell[q]]
    if sh.have_shadows:
        # out of range 0, else occluded 1 or visible 2 (OCCLUSION_*)
        sensor_range = sh.sensor_range
        for q in range(n_px):
            d = px_dist[q]
            shade[q] = np.uint8(d <= sensor_range) * (np.uint8(1) + np.uint8(d <= depth[px_bin[q]]))
    else:
        shade[:] = OCCLUSION_VISIBLE


@njit(nogil=True, inline="always")
def _fill_layers(pix, layers, code, route, occupant, shade):  # pragma: no cover - compiled
    """Write each asked-for layer into its plane (``pix.slot``: the plane of each layer, -1: not drawn)."""
    n_px = pix.size * pix.size
    slot = pix.slot
    s_drv, s_lane, s_route, s_occ, s_occl = slot[0], slot[1], slot[2], slot[3], slot[4]
    flat = layers.reshape(layers.shape[0], n_px)
    if s_drv >= 0:
        for q in range(n_px):
            flat[s_drv, q] = code[q] & ON_ROAD
    if s_lane >= 0:
        for q in range(n_px):
            flat[s_lane, q] = code[q] >> 1  # ON_LANE_LINE
    if s_route >= 0:
        flat[s_route, :] = route
    if s_occ >= 0:
        for q in range(n_px):
            flat[s_occ, q] = occupant[q] > 0
    if s_occl >= 0:
        flat[s_occl, :] = shade


@njit(nogil=True, inline="always")
def _compose_rgb(n_px, role, occupant, route, code, shade, rgb):  # pragma: no cover - compiled
    """The RGB view: road users over route over lane lines over road, each pixel shaded by its level."""
    shaded = SHADED_PALETTE
    image = rgb.reshape(n_px, 3)
    for q in range(n_px):
        occ = occupant[q]
        if occ != 0:
            colour = EGO if occ < 0 else ROLE_BASE + role[occ - 1]
            level = OCCLUSION_VISIBLE
        else:
            colour = _GROUND[code[q] | (route[q] << 2)]
            level = shade[q]
        image[q, 0] = shaded[level, colour, 0]
        image[q, 1] = shaded[level, colour, 1]
        image[q, 2] = shaded[level, colour, 2]


_GROUND = np.array([BACKGROUND, ROAD, LANE, LANE, ROUTE, ROUTE, ROUTE, ROUTE], dtype=np.int64)
"""The ground's palette row by ``raster_codes`` byte plus 4 on the route (the route over lane
lines over the road)."""


class EgoViewRenderer:
    """An ego-centred RGB view for ``render()``: the rasters' RGB at a larger size, with shadows."""

    def __init__(self, size: int = 256, resolution: float = 0.25, sensor_range: float = 50.0):
        from smarts.sensors.occlusion import ShadowCaster

        self.sensor = RasterSensor(RasterInterface(size=size, resolution=resolution, layers=(), rgb=True))
        self.shadows = ShadowCaster(sensor_range)

    def render(self, sim: Simulation, agent: int) -> np.ndarray:
        agents = np.array([agent], dtype=np.int64)
        rows = sim.agent_row[agents]
        return self.sensor.observe(sim, agents, rows, self.shadows.scan(sim, agents, rows))["rgb"][0]


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
