"""What a car can physically do in one step.

The pose action spaces let an agent ask for any next pose; these limits turn such a request into
one a real car could have achieved, so a policy cannot teleport, spin in place or stop instantly.
The same numbers bound the lane controller, so every kinematic controller obeys one envelope.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class ReachLimits:
    """Physical envelope of a passenger car (defaults) for one simulation step.

    Attributes:
        max_speed: highest forward speed, m/s (22.22 m/s = 80 km/h).
        max_accel: largest increase of speed magnitude, m/s^2.
        max_decel: largest decrease of speed magnitude (braking), m/s^2.
        max_yaw_rate: largest heading change rate, rad/s.
        max_curvature: largest path curvature, 1/m (the inverse of the smallest turning radius).
            Heading can only change while moving: |dheading| <= max_curvature * distance travelled.
        max_slip: how far, in rad, the displacement direction may deviate from the chord direction
            (the mean of the old and new heading) along which a non-slipping bicycle moves.
        allow_reverse: whether the car may drive backwards. When False a backward request is a
            request to stop (slow down as much as the deceleration limit allows).
        max_reverse_speed: highest backward speed, m/s; only used when ``allow_reverse`` is True.
    """

    max_speed: float = 22.22
    max_accel: float = 4.0
    max_decel: float = 9.0
    max_yaw_rate: float = 1.2
    max_curvature: float = 1.0 / 5.0
    max_slip: float = 0.1
    allow_reverse: bool = False
    max_reverse_speed: float = 5.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "allow_reverse":
                if not isinstance(value, bool):
                    raise ValueError(f"ReachLimits.allow_reverse must be a bool, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"ReachLimits.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"ReachLimits.{f.name} must be finite, got {value!r}")
            if f.name == "max_slip":
                if not 0.0 <= value < math.pi / 2:
                    raise ValueError(f"ReachLimits.max_slip must be in [0, pi/2) rad, got {value!r}")
            elif value <= 0.0:
                raise ValueError(f"ReachLimits.{f.name} must be positive, got {value!r}")

    @property
    def min_turning_radius(self) -> float:
        """Radius of the tightest circle the car can drive, m."""
        return 1.0 / self.max_curvature
