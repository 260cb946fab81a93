"""Compiled kernel of headings from positions (see ``recording.kinematics_from_positions``)."""

from __future__ import annotations

import math

import numpy as np

from smarts.compiled import njit


@njit(nogil=True)
def chord_headings(sx, sy, start, end, reach, window):  # pragma: no cover - compiled
    """Per sample ``i`` of concatenated tracks (``start[i]``/``end[i]``: its track's first index and
    one past its last): the direction of the chord between the nearest earlier and later samples at
    least ``reach`` metres from it, looked for within ``window`` samples; where only one side has
    such a sample, the chord from ``i`` to the nearest one twice as far on that side (or the
    farthest found). Returns the headings and whether a chord was found (bool)."""
    n = sx.shape[0]
    heading = np.zeros(n)
    defined = np.zeros(n, dtype=np.bool_)
    r1, r2 = reach * reach, 4.0 * reach * reach
    for i in range(n):
        s, e = start[i], end[i]
        f1, f2 = -1, -1
        lim = min(e - 1, i + window)
        for j in range(i + 1, lim + 1):
            dx, dy = sx[j] - sx[i], sy[j] - sy[i]
            d = dx * dx + dy * dy
            if f1 < 0 and d >= r1:
                f1 = j
            if d >= r2:
                f2 = j
                break
        b1, b2 = -1, -1
        lim = max(s, i - window)
        for j in range(i - 1, lim - 1, -1):
            dx, dy = sx[i] - sx[j], sy[i] - sy[j]
            d = dx * dx + dy * dy
            if b1 < 0 and d >= r1:
                b1 = j
            if d >= r2:
                b2 = j
                break
        if f1 >= 0 and b1 >= 0:  # a chord across the frame, each end ``reach`` away
            a, c = b1, f1
        elif f1 >= 0:  # one side only (a track's start, or just before moving off): twice as far
            a, c = i, (f2 if f2 >= 0 else f1)
        elif b1 >= 0:
            a, c = (b2 if b2 >= 0 else b1), i
        else:
            continue
        heading[i] = math.atan2(sy[c] - sy[a], sx[c] - sx[a])
        defined[i] = True
    return heading, defined
