"""How lane-relative commands become motion (``smarts.dynamics.lane_relative`` runs them): the
settings a policy learns against, travelling in its checkpoint and read by configs without the
controller's compiled kernels."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class LaneRelativeParams:
    """How commands become motion (documented because policies learn against them)."""

    speed_time_constant: float = 2.0
    """s: the acceleration is the speed error divided by this."""
    max_accel: float = 2.0
    """m/s^2: the largest acceleration (the Humanness comfort limit)."""
    max_decel: float = 6.0
    """m/s^2: the hardest braking."""
    max_jerk: float = 0.8
    """m/s^3: how fast the acceleration may change from one step to the next (within the
    Humanness comfort limit of 0.9, with room for rounding)..."""
    brake_jerk: float = 4.0
    """m/s^3: ...except when braking harder than ``comfort_decel`` is asked for: an emergency."""
    comfort_decel: float = 2.0
    """m/s^2: braking beyond this is an emergency (``brake_jerk``)."""
    lane_change_time: float = 5.0
    """s: duration of the lateral profile of one lane change."""
    lookahead_time: float = 0.6
    """s of travel to the pure-pursuit point."""
    min_lookahead: float = 2.5
    """m: the pure-pursuit point is never closer than this."""
    threshold: float = 0.5
    """|lane_change| above this asks for a change (or a branch)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"LaneRelativeParams.{f.name}: expected a finite number, got {value!r}")
            if value <= 0 or (f.name == "threshold" and value >= 1):
                raise ValueError(
                    f"LaneRelativeParams.{f.name}: expected a number in (0, {'1' if f.name == 'threshold' else 'inf'}), got {value!r}"
                )
