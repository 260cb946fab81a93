"""A 2D lidar: evenly spaced rays from the ego's centre hitting boxes and road edges.

Per agent and ray: the distance to the first hit (the range when nothing is hit) and what was hit.
Boxes (vehicles and pedestrians, not the ego) are intersected only by the rays inside their angular
extent. Road edges are where a ray first leaves the drivable raster: the ray jumps ahead by the
road clearance field (distance to the nearest off-road cell), so open road costs a few steps, and
the crossing is refined by bisection. A ray that starts off the road hits an edge at 0.

Noise (Gaussian, ``noise`` metres) is added to hit distances only, clipped to [0, range], from a
generator seeded with the scenario seed and reseeded at every episode start.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numba
import numpy as np

from smarts.compiled import njit
from smarts.core.simulation import Scope, Simulation
from smarts.core.vehicle_table import COLUMN, Role
from smarts.sensors.interface import LidarInterface
from smarts.sensors.map_fields import cell_grid, map_fields
from smarts.sensors.rays import box_interval, parallel_worth_it, ray_box

HIT_NONE, HIT_VEHICLE, HIT_PEDESTRIAN, HIT_ROAD_EDGE = 0, 1, 2, 3
_NOISE_STREAM = 0x1D4


class LidarSensor:
    """``lidar`` float32[rays] (m) and ``lidar_hit`` float32[rays] (``HIT_*`` codes)."""

    def __init__(self, config: LidarInterface, stream: int = 0):
        self.config = config
        self._stream = stream
        self.episode_streams: dict[int, int] = {}
        """Episode -> the stream this sensor's group has in it (its rank among the episode's own
        interface groups, as a simulation of that episode alone numbers them); default ``stream``."""
        self._rngs: dict[int, tuple] = {}  # episode -> (noise generator, (seed, step) it last drew at)

    def spaces(self) -> dict[str, gym.spaces.Box]:
        r, rng = self.config.rays, np.float32(self.config.range)
        return {
            "lidar": gym.spaces.Box(0.0, rng, (r,), np.float32),
            "lidar_hit": gym.spaces.Box(0.0, float(HIT_ROAD_EDGE), (r,), np.float32),
        }

    def observe(self, sim: Simulation, agents: np.ndarray, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Scans of ``agents`` (rows ``rows``), each among its own episode's road users, on its
        own map; the noise of each episode comes from that episode's seed."""
        cfg = self.config
        n = rows.shape[0]
        dist = np.empty((n, cfg.rays), dtype=np.float32)
        hit = np.empty((n, cfg.rays), dtype=np.float32)
        scope = sim.scope(agents)
        maps = sim.episode_map[sim.agent_episode[agents]]
        for m in np.unique(maps).tolist() if n else []:
            idx = np.flatnonzero(maps == m)
            f = map_fields(sim.map_stack.maps[m])
            d, h = (
                (dist, hit)
                if len(idx) == n
                else (np.empty((len(idx), cfg.rays), np.float32), np.empty((len(idx), cfg.rays), np.float32))
            )
            kernel = lidar_scan_parallel if parallel_worth_it(len(idx)) else lidar_scan
            part = Scope(scope.alive, scope.lo[idx], scope.hi[idx], scope.base[idx])
            grid = cell_grid(f, f.road_clearance)
            kernel(sim.table.data, sim.table.role, part, rows[idx], cfg.range, grid, d, h)
            if len(idx) != n:
                dist[idx], hit[idx] = d, h
        if cfg.noise > 0 and n:
            episode = sim.agent_episode[agents]
            for b in np.unique(episode).tolist():
                mine = np.flatnonzero(episode == b)
                noise = self._generator(b, sim.episode_seed[b], int(sim.episode_step[b])).standard_normal(
                    (len(mine), cfg.rays), dtype=np.float32
                )
                noise *= np.float32(cfg.noise)
                noise[hit[mine] == HIT_NONE] = 0.0
                dist[mine] += noise
            np.clip(dist, 0.0, np.float32(cfg.range), out=dist)
        return {"lidar": dist, "lidar_hit": hit}

    def _generator(self, episode: int, seed: int, step: int) -> np.random.Generator:
        # A new episode (step 0, or time went back) restarts the noise sequence of its seed.
        rng, last = self._rngs.get(episode, (None, None))
        if rng is None or last is None or seed != last[0] or step == 0 or step < last[1]:
            rng = np.random.default_rng([seed, _NOISE_STREAM, self.episode_streams.get(episode, self._stream)])
        self._rngs[episode] = (rng, (seed, step))
        return rng


@njit(nogil=True)
def lidar_scan(data, role, scope, rows, max_range, grid, dist, hit):  # pragma: no cover - compiled
    """Each agent's rays (``rows[i]`` among the live rows of its episode, ``scope``, a
    ``smarts.core.simulation.Scope``)."""
    for i in range(rows.shape[0]):
        _scan_one(data, role, scope.alive[scope.lo[i] : scope.hi[i]], rows[i], max_range, grid, dist[i], hit[i])


@njit(nogil=True, parallel=True)
def lidar_scan_parallel(data, role, scope, rows, max_range, grid, dist, hit):  # pragma: no cover - compiled
    """``lidar_scan`` with the agents spread over threads (each agent's rays are its own)."""
    for i in numba.prange(rows.shape[0]):
        _scan_one(data, role, scope.alive[scope.lo[i] : scope.hi[i]], rows[i], max_range, grid, dist[i], hit[i])


@njit(nogil=True)
def _scan_one(data, role, alive, r, max_range, grid, dist, hit):  # pragma: no cover - compiled
    n_rays = dist.shape[0]
    step = 2.0 * math.pi / n_rays
    px, py, h = data[_X, r], data[_Y, r], data[_H, r]
    dist[:] = max_range
    hit[:] = HIT_NONE
    ray_c, ray_s = np.empty(n_rays), np.empty(n_rays)
    for k in range(n_rays):
        a = k * step + h
        ray_c[k], ray_s[k] = math.cos(a), math.sin(a)
    for j in alive:
        if j == r:
            continue
        bx, by, bh = data[_X, j], data[_Y, j], data[_H, j]
        hl, hw = 0.5 * data[_LENGTH, j], 0.5 * data[_WIDTH, j]
        if math.hypot(bx - px, by - py) - math.hypot(hl, hw) > max_range:
            continue
        lo, hi, inside = box_interval(px, py, h, bx, by, bh, hl, hw)
        if inside:
            continue
        kind = HIT_PEDESTRIAN if role[j] == _PEDESTRIAN else HIT_VEHICLE
        bc, bs = math.cos(bh), math.sin(bh)
        for k in range(int(math.ceil(lo / step)), int(math.floor(hi / step)) + 1):
            kk = k % n_rays
            if k == kk:
                t = ray_box(px, py, ray_c[k], ray_s[k], bx, by, bc, bs, hl, hw)
            else:  # a ray past -pi or pi, numbered as the box's extent numbers it
                a = k * step + h
                t = ray_box(px, py, math.cos(a), math.sin(a), bx, by, bc, bs, hl, hw)
            if t < dist[kk]:
                dist[kk] = t
                hit[kk] = kind
    # Road edges: first each ray's stretch where it leaves the road, then all those stretches
    # bisected together (independent chains of lookups, so their latencies overlap).
    lo, hi = np.empty(n_rays), np.empty(n_rays)
    crossing = np.empty(n_rays, dtype=np.int64)
    m = 0
    if _clearance_at(px, py, grid) == 0:
        for k in range(n_rays):
            if 0.0 < dist[k]:
                dist[k] = 0.0
                hit[k] = HIT_ROAD_EDGE
        return
    for k in range(n_rays):
        t_road, t_off = _edge_stretch(px, py, ray_c[k], ray_s[k], dist[k], grid)
        if t_off >= 0.0:
            lo[m], hi[m], crossing[m] = t_road, t_off, k
            m += 1
    for _ in range(_BISECTIONS):
        for q in range(m):
            k = crossing[q]
            mid = 0.5 * (lo[q] + hi[q])
            if _clearance_at(px + mid * ray_c[k], py + mid * ray_s[k], grid) == 0:
                hi[q] = mid
            else:
                lo[q] = mid
    for q in range(m):
        k = crossing[q]
        if hi[q] < dist[k]:
            dist[k] = hi[q]
            hit[k] = HIT_ROAD_EDGE


@njit(nogil=True, inline="always")
def _clearance_at(x, y, grid):  # pragma: no cover - compiled
    cx = min(max((x - grid.origin[0]) * grid.inv_res, 0.0), grid.cell_max[0])
    cy = min(max((y - grid.origin[1]) * grid.inv_res, 0.0), grid.cell_max[1])
    return grid.cells[int(cy) * grid.width + int(cx)]


@njit(nogil=True, inline="always")
def _edge_stretch(px, py, dx, dy, limit, grid):  # pragma: no cover - compiled
    """Along a ray that starts on the road: the last distance known on the road and the first
    sampled off it, where it leaves within ``limit`` (else -1 for the latter). Jumps by the road
    clearance: any point of an off-road cell lies at least (clearance - sqrt(2)) cells away."""
    res = 1.0 / grid.inv_res
    c = _clearance_at(px, py, grid)
    t_road = 0.0
    while t_road < limit:
        t = min(t_road + max(c - 1.5, 0.5) * res, limit)
        c = _clearance_at(px + t * dx, py + t * dy, grid)
        if c == 0:
            return t_road, t
        t_road = t
    return t_road, -1.0


_BISECTIONS = 10  # halvings of the stretch where a ray leaves the road: 1/1024 of its length


_PEDESTRIAN = int(Role.PEDESTRIAN)

_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
