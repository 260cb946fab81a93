"""Compiled ray and box primitives shared by the occlusion, lidar and raster sensors.

Every sensor looks from the ego's centre (its sensor position) in the ego frame: angles are
relative to the ego's heading, counter-clockwise positive.
"""

from __future__ import annotations

import math
import os

import numba

from smarts.compiled import njit

_TWO_PI = 2.0 * math.pi
PARALLEL_AGENTS = 16
"""Agents from which the sensors spread their per-agent work over threads; below it waking the
threads costs more than it saves."""
SENSOR_THREADS_VARIABLE = "SMARTS_SENSOR_THREADS"
"""Threads the occlusion, lidar and raster sensors may use (default 1: one thread per process,
like the rest of the step; numba's ``NUMBA_NUM_THREADS`` caps it). Each agent's result is
computed alone, so any number gives the same observations."""


def sensor_threads() -> int:
    """The threads the sensors use (``SMARTS_SENSOR_THREADS``, read at each call)."""
    text = os.environ.get(SENSOR_THREADS_VARIABLE, "1")
    try:
        wanted = int(text)
    except ValueError:
        raise ValueError(f"{SENSOR_THREADS_VARIABLE}: expected a positive integer, got {text!r}") from None
    if wanted < 1:
        raise ValueError(f"{SENSOR_THREADS_VARIABLE}: expected a positive integer, got {text!r}")
    return min(wanted, numba.config.NUMBA_NUM_THREADS)


def parallel_worth_it(n_agents: int) -> bool:
    """Whether ``n_agents`` agents' sensors run on threads (more than one allowed, and enough
    agents); sets numba's thread count for the call when they do."""
    if n_agents < PARALLEL_AGENTS:
        return False
    threads = sensor_threads()
    if threads < 2:
        return False
    numba.set_num_threads(threads)
    return True


GRAZE = 1e-6  # metres: a ray touching a box corner still hits it


@njit(nogil=True, inline="always")
def ray_box(px, py, dx, dy, bx, by, bc, bs, half_length, half_width):  # pragma: no cover - compiled
    """Distance along the unit ray (px, py) + t (dx, dy), t >= 0, to where it enters the box
    centred at (bx, by) with heading cosine/sine (bc, bs); inf when it misses."""
    ox, oy = px - bx, py - by
    return slab(bc * ox + bs * oy, -bs * ox + bc * oy, bc * dx + bs * dy, -bs * dx + bc * dy, half_length, half_width)


@njit(nogil=True, inline="always")
def slab(lx, ly, ldx, ldy, half_length, half_width):  # pragma: no cover - compiled
    """``ray_box`` with the ray already in the box frame: origin (lx, ly), unit direction (ldx, ldy)."""
    t_in, t_out = -math.inf, math.inf
    if abs(ldx) < 1e-12:
        if abs(lx) > half_length + GRAZE:
            return math.inf
    else:
        ta, tb = (-half_length - lx) / ldx, (half_length - lx) / ldx
        t_in, t_out = max(t_in, min(ta, tb)), min(t_out, max(ta, tb))
    if abs(ldy) < 1e-12:
        if abs(ly) > half_width + GRAZE:
            return math.inf
    else:
        ta, tb = (-half_width - ly) / ldy, (half_width - ly) / ldy
        t_in, t_out = max(t_in, min(ta, tb)), min(t_out, max(ta, tb))
    t_in = max(t_in, 0.0)
    if t_out < t_in - GRAZE:
        return math.inf
    return t_in


@njit(nogil=True, inline="always")
def box_interval(px, py, heading, bx, by, bh, half_length, half_width):  # pragma: no cover - compiled
    """Angular extent [lo, hi] (ego frame, radians; lo may be below -pi and hi above pi) of a box
    seen from (px, py), and whether the point lies inside the box (then the extent is undefined)."""
    bc, bs = math.cos(bh), math.sin(bh)
    ox, oy = px - bx, py - by
    if abs(bc * ox + bs * oy) <= half_length and abs(-bs * ox + bc * oy) <= half_width:
        return 0.0, 0.0, True
    centre = math.atan2(by - py, bx - px)
    lo, hi = math.inf, -math.inf
    for k in range(4):
        f = half_length if k < 2 else -half_length
        side = half_width if k == 0 or k == 3 else -half_width
        cx, cy = bx + bc * f - bs * side, by + bs * f + bc * side
        a = math.atan2(cy - py, cx - px) - centre
        a -= _TWO_PI * math.floor((a + math.pi) / _TWO_PI)  # wrap to [-pi, pi)
        lo, hi = min(lo, a), max(hi, a)
    rel = centre - heading
    rel -= _TWO_PI * math.floor((rel + math.pi) / _TWO_PI)
    return rel + lo, rel + hi, False
