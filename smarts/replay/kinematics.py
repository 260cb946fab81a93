"""Compiled kernel of headings from positions (see ``recording.kinematics_from_positions``)."""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def chord_headings(sx, sy, start, end, reach, window):  # pragma: no cover - compiled
    """Per sample ``i`` of concatenated tracks (``start[i]``/``end[i]``: its track's first index and
    one past its last): the direction of the chord between the nearest earlier and later samples at
    least ``reach`` metres from it (``i`` itself for a side where none is), looked for within
    ``window`` samples; and whether either end was found (bool)."""
    n = sx.shape[0]
    heading = np.zeros(n)
    defined = np.zeros(n, dtype=np.bool_)
    r2 = reach * reach
    for i in range(n):
        s, e = start[i], end[i]
        fwd = -1
        lim = min(e - 1, i + window)
        for j in range(i + 1, lim + 1):
            dx, dy = sx[j] - sx[i], sy[j] - sy[i]
            if dx * dx + dy * dy >= r2:
                fwd = j
                break
        back = -1
        lim = max(s, i - window)
        for j in range(i - 1, lim - 1, -1):
            dx, dy = sx[i] - sx[j], sy[i] - sy[j]
            if dx * dx + dy * dy >= r2:
                back = j
                break
        if fwd >= 0 or back >= 0:
            a = back if back >= 0 else i
            c = fwd if fwd >= 0 else i
            heading[i] = math.atan2(sy[c] - sy[a], sx[c] - sx[a])
            defined[i] = True
    return heading, defined
