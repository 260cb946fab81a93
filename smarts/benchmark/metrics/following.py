"""Follow margin and time gap: what the env logger writes for the SFD metric.

The logger calls these every step for all agents at once, so they take arrays (or scalars) and
are a handful of numpy operations. ``gap_m`` is the free space along the lane between the ego's
front bumper and its lead's rear bumper.

- Follow margin FM = standstill distance + safe headway * ego speed (a constant-time-gap spacing
  policy). The ego is *inside* the margin when ``gap_m <= FM``: too close, which SFD scores as 1.
- Time gap to FM = (gap_m - FM) / ego speed: how long the ego, at its current speed, would take
  to close the extra space beyond the margin. 0 inside the margin; +inf when the ego stands
  still outside it. :func:`time_gap_to_margin` returns it together with the inside flag.
"""

from __future__ import annotations

import numpy as np

from smarts.benchmark.metrics.params import FollowingParams, MetricParams


def _following(params: MetricParams | FollowingParams) -> FollowingParams:
    return params.following if isinstance(params, MetricParams) else params


def follow_margin(speed: np.ndarray | float, params: MetricParams | FollowingParams) -> np.ndarray | float:
    """FM in metres for ego ``speed`` (m/s; negative speeds count as 0)."""
    f = _following(params)
    margin = f.standstill_distance_m + f.safe_headway_s * np.maximum(speed, 0.0)
    return float(margin) if np.ndim(margin) == 0 else margin


def in_follow_margin(
    gap_m: np.ndarray | float,
    ego_speed: np.ndarray | float,
    params: MetricParams | FollowingParams,
) -> np.ndarray | bool:
    """True where the free space to the lead is at most the follow margin."""
    inside = np.less_equal(gap_m, follow_margin(ego_speed, params))
    return bool(inside) if np.ndim(inside) == 0 else inside


def time_gap_to_margin(
    gap_m: np.ndarray | float,
    ego_speed: np.ndarray | float,
    params: MetricParams | FollowingParams,
) -> tuple[np.ndarray | float, np.ndarray | bool]:
    """``(time gap to FM in s, inside FM)``: the two following columns the logger writes.

    The time gap is ``(gap_m - FM) / ego speed``: 0 inside FM, +inf when stopped outside it,
    NaN where ``gap_m`` is NaN (no lead). Inside FM means ``gap_m <= FM``.
    """
    f = _following(params)
    speed = np.maximum(ego_speed, 0.0)
    excess = np.subtract(gap_m, f.standstill_distance_m + f.safe_headway_s * speed)
    with np.errstate(divide="ignore", invalid="ignore"):
        gap_s = excess / speed  # +inf when stopped outside FM, -inf inside, NaN for 0/0
    # Inside FM counts as 0 s; NaN gaps stay NaN (maximum propagates NaN).
    gap_s = np.where(excess == 0.0, 0.0, np.maximum(gap_s, 0.0))
    inside = excess <= 0.0
    if np.ndim(gap_s) == 0:
        return float(gap_s), bool(inside)
    return gap_s, inside
