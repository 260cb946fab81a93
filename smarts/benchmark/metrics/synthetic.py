"""Hand-built episode logs: a benign baseline that examples and tests override column by column.

The baseline is a vehicle cruising at constant speed along the centre of a straight lane, below
the limit, with no events, so every cost is 0 except what the caller overrides (and progress,
which follows from the route distances given).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smarts.benchmark.metrics.log import AgentTrace, EpisodeLog


def make_trace(
    num_steps: int,
    dt: float = 0.1,
    *,
    speed: float | np.ndarray = 10.0,
    initial_route_distance: float = 100.0,
    with_following: bool = False,
    **columns: Any,
) -> AgentTrace:
    """A ``num_steps`` trace; keyword ``columns`` replace the baseline arrays by name.

    Baseline: ``time = dt, 2 dt, ...``; x advancing at ``speed`` (a scalar or per-step array); zero accelerations and jerks;
    on the lane centre of a 3.5 m lane with a 20 m/s limit; ``route_distance_to_goal`` shrinking
    from ``initial_route_distance`` by the distance driven (floored at 0); no flags set. With
    ``with_following`` the lead is visible in lane with a 1.5 s time gap to the follow margin.
    """
    n = int(num_steps)
    time = dt * np.arange(1, n + 1, dtype=np.float64)
    speeds = np.broadcast_to(np.asarray(speed, dtype=np.float64), (n,)).copy()
    driven = np.cumsum(speeds) * dt
    zeros = np.zeros(n)
    false = np.zeros(n, dtype=bool)
    base: dict[str, Any] = {
        "time": time,
        "x": driven,
        "y": zeros.copy(),
        "heading": zeros.copy(),
        "speed": speeds,
        "accel_long": zeros.copy(),
        "accel_lat": zeros.copy(),
        "jerk_long": zeros.copy(),
        "jerk_lat": zeros.copy(),
        "lane_offset": zeros.copy(),
        "lane_width": np.full(n, 3.5),
        "speed_limit": np.full(n, 20.0),
        "wrong_way": false.copy(),
        "partial_off_road": false.copy(),
        "off_road": false.copy(),
        "route_distance_to_goal": np.maximum(initial_route_distance - driven, 0.0),
        "goal_reached": false.copy(),
    }
    if with_following:
        base["follow_time_gap"] = np.full(n, 1.5)
        base["in_follow_margin"] = false.copy()
        base["lead_in_lane_and_visible"] = np.ones(n, dtype=bool)
    unknown = set(columns) - set(AgentTrace.__dataclass_fields__)
    if unknown:
        raise TypeError(f"make_trace: unknown column(s) {sorted(unknown)}")
    base.update(columns)
    return AgentTrace(**base)


def make_episode(
    traces: dict[str, AgentTrace],
    *,
    scenario: str = "scenario",
    task: str = "collaborative",
    episode: int = 0,
    seed: int | None = 0,
    dt: float = 0.1,
    time_limit: float = 10.0,
    goal_radius: float = 2.0,
    initial_route_distance: dict[str, float] | float = 100.0,
    failure: str | None = None,
    info: dict[str, Any] | None = None,
    end_time: float | None = None,
    signals: int = 0,
) -> EpisodeLog:
    """Wrap traces in an :class:`EpisodeLog`; a single float sets every agent's initial distance."""
    if not isinstance(initial_route_distance, dict):
        initial_route_distance = {a: float(initial_route_distance) for a in traces}
    return EpisodeLog(
        scenario=scenario,
        task=task,
        episode=episode,
        seed=seed,
        dt=dt,
        time_limit=time_limit,
        goal_radius=goal_radius,
        agents=dict(traces),
        end_time=end_time,
        initial_route_distance=initial_route_distance,
        failure=failure,
        info=dict(info or {}),
        signals=signals,
    )
