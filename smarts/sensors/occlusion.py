"""Occlusion: what each ego can see from its sensor position, for all agents in one pass.

Every road user's box (vehicles and pedestrians, the ego excepted) casts a shadow. Per agent, a
polar depth buffer of ``SHADOW_BINS`` angular bins around the ego holds the distance to the nearest
box along each bin and which row it belongs to. A box writes only the bins its angular extent
overlaps, with its ray clamped into that extent so that even a box narrower than a bin is hit.

From the buffer:
- a road user's visible fraction is the share of its angular extent where it is the nearest box and
  within the sensor range (1: fully visible, 0: hidden or out of range);
- a point at (angle, distance) is occluded when the distance exceeds the bin's depth, which gives
  the occlusion raster with one comparison per pixel.
A box that contains the sensor (a collision) is ignored as an occluder and counted as visible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from smarts.compiled import njit
from smarts.core.simulation import Simulation
from smarts.core.vehicle_table import COLUMN
from smarts.sensors.rays import box_interval, parallel_worth_it, slab

SHADOW_BINS = 1440
"""Angular bins of the depth buffer (0.25 degree each: 4 cm across at 10 m)."""


@dataclass
class Shadows:
    """Per-agent depth buffers and visible fractions, in the order of the rows scanned (views
    into the caster's buffers: valid until its next scan)."""

    depth: np.ndarray  # float64[n, SHADOW_BINS] metres to the nearest box, inf where none
    owner: np.ndarray  # int64[n, SHADOW_BINS] table row of that box, -1 where none
    visible: np.ndarray  # float32[n, capacity] visible fraction of each live row of the agent's
    # episode, by its row within the episode (0 elsewhere)
    range: float


class ShadowCaster:
    """Keeps the scratch buffers between steps; ``scan`` fills them for the agents given."""

    def __init__(self, sensor_range: float):
        self.range = float(sensor_range)
        self._depth = np.empty((0, SHADOW_BINS))
        self._owner = np.empty((0, SHADOW_BINS), dtype=np.int64)
        self._visible = np.empty((0, 0), dtype=np.float32)

    def scan(self, sim: Simulation, agents: np.ndarray, rows: np.ndarray) -> Shadows:
        """Shadows of ``agents`` (rows ``rows``), each among its own episode's road users."""
        n, cap = rows.shape[0], sim.episode_capacity
        if self._depth.shape[0] < n or self._visible.shape[1] != cap:
            m = max(n, self._depth.shape[0])
            self._depth = np.empty((m, SHADOW_BINS))
            self._owner = np.empty((m, SHADOW_BINS), dtype=np.int64)
            self._visible = np.zeros((m, cap), dtype=np.float32)
        depth, owner, visible = self._depth[:n], self._owner[:n], self._visible[:n]
        scope = sim.scope(agents)
        kernel = cast_shadows_parallel if parallel_worth_it(n) else cast_shadows
        kernel(sim.table.data, scope.alive, scope.lo, scope.hi, scope.base, rows, self.range, depth, owner, visible)
        return Shadows(depth, owner, visible, self.range)


@njit(nogil=True)
def cast_shadows(
    data, alive, alive_lo, alive_hi, row_base, rows, sensor_range, depth, owner, visible
):  # pragma: no cover - compiled
    """Fill ``depth``/``owner`` [n, bins] and ``visible`` [n, capacity] for the agents' rows, each
    among ``alive[alive_lo[i]:alive_hi[i]]`` (``visible`` by row within the episode, ``row -
    row_base[i]``; ``owner`` holds global rows)."""
    for i in range(rows.shape[0]):
        _cast_one(
            data, alive[alive_lo[i] : alive_hi[i]], row_base[i], rows[i], sensor_range, depth[i], owner[i], visible[i]
        )


@njit(nogil=True, parallel=True)
def cast_shadows_parallel(
    data, alive, alive_lo, alive_hi, row_base, rows, sensor_range, depth, owner, visible
):  # pragma: no cover - compiled
    """``cast_shadows`` with the agents spread over threads (each agent's buffers are its own, so
    the result is the same)."""
    for i in numba.prange(rows.shape[0]):
        _cast_one(
            data, alive[alive_lo[i] : alive_hi[i]], row_base[i], rows[i], sensor_range, depth[i], owner[i], visible[i]
        )


@njit(nogil=True)
def _cast_one(data, alive, base, r, sensor_range, depth, owner, visible):  # pragma: no cover - compiled
    """One agent's depth buffer, owners and visible fractions."""
    n_bins = depth.shape[0]
    bin_width = 2.0 * math.pi / n_bins
    turn_c, turn_s = math.cos(bin_width), math.sin(bin_width)
    cand = np.empty(alive.shape[0], dtype=np.int64)
    bin_count = np.empty(alive.shape[0], dtype=np.int64)
    px, py, h = data[_X, r], data[_Y, r], data[_H, r]
    depth[:] = math.inf
    owner[:] = -1
    visible[:] = 0.0  # (rows of the episode that are not alive stay 0)
    m = 0
    for j in alive:
        if j == r:
            continue
        bx, by, bh = data[_X, j], data[_Y, j], data[_H, j]
        hl, hw = 0.5 * data[_LENGTH, j], 0.5 * data[_WIDTH, j]
        if math.hypot(bx - px, by - py) - math.hypot(hl, hw) > sensor_range:
            continue
        lo, hi, inside = box_interval(px, py, h, bx, by, bh, hl, hw)
        if inside:
            visible[j - base] = 1.0
            continue
        b0 = int(math.floor((lo + math.pi) / bin_width))
        b1 = int(math.floor((hi + math.pi) / bin_width))
        cand[m], bin_count[m] = j, b1 - b0 + 1
        m += 1
        # Rays in the box's frame; inner bins turn the previous direction by one bin width.
        bc, bs = math.cos(bh), math.sin(bh)
        lx, ly = bc * (px - bx) + bs * (py - by), -bs * (px - bx) + bc * (py - by)
        ldx, ldy = 1.0, 0.0
        for b in range(b0, b1 + 1):
            if b <= b0 + 1 or b == b1:
                a = min(max((b + 0.5) * bin_width - math.pi, lo), hi) + h - bh
                ldx, ldy = math.cos(a), math.sin(a)
            else:
                ldx, ldy = ldx * turn_c - ldy * turn_s, ldx * turn_s + ldy * turn_c
            t = slab(lx, ly, ldx, ldy, hl, hw)
            k = b + n_bins if b < 0 else (b - n_bins if b >= n_bins else b)  # (b is within one turn)
            if t < depth[k]:
                depth[k] = t
                owner[k] = j
    # A box owns bins of its own extent only: one pass over the buffer counts each box's.
    seen = np.zeros(visible.shape[0], dtype=np.int64)
    for k in range(n_bins):
        if owner[k] >= 0 and depth[k] <= sensor_range:
            seen[owner[k] - base] += 1
    for q in range(m):
        visible[cand[q] - base] = seen[cand[q] - base] / bin_count[q]


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
