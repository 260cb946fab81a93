"""The task rewards' weights and limits (``smarts.env.task_rewards`` computes the rewards): a plain,
validated record a training config holds, apart from the reward code and its simulator imports."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

TASK_REWARDS = ("platoon", "drive")


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the task reward terms (see the module docstring) and the limits they use."""

    task: str = "platoon"
    # platoon
    follow: float = 1.0
    target_gap: float = 0.5
    """s beyond the follow margin where the follow term peaks (just outside the margin, which SFD
    scores best, with room to spare: inside it SFD counts the lead as lost)."""
    travel: float = 0.02
    # drive
    progress: float = 0.1
    goal: float = 10.0
    time: float = 0.05
    # shared
    comfort: float = 0.1
    lane_centre: float = 0.1
    speeding: float = 0.5
    wrong_way: float = 0.5
    partial_off_road: float = 0.5
    red_light: float = 0.0
    """Entering a junction from a road lane while the junction lane's signal is red (as the
    benchmark's RC rule counts it; yellow is no violation). 0 leaves it out."""
    collision: float = 20.0
    off_road: float = 20.0
    # limits (the benchmark's defaults)
    standstill_distance: float = 2.5
    headway: float = 1.0
    max_time_gap: float = 3.0
    jerk_long_max: float = 0.9
    jerk_lat_max: float = 0.9
    accel_long_max: float = 2.0
    accel_lat_max: float = 1.47

    def __post_init__(self) -> None:
        if self.task not in TASK_REWARDS:
            raise ValueError(f"reward.task: expected one of {', '.join(TASK_REWARDS)}, got {self.task!r}")
        for f in fields(self):
            if f.name == "task":
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
                raise ValueError(f"reward.{f.name}: expected a finite number >= 0, got {value!r}")
        for name in ("headway", "max_time_gap", "jerk_long_max", "jerk_lat_max", "accel_long_max", "accel_lat_max"):
            if getattr(self, name) <= 0:
                raise ValueError(f"reward.{name}: expected a positive number, got {getattr(self, name)!r}")
