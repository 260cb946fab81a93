"""Vehicle dynamics: action spaces, their controllers and the physical limits they obey.

The pybullet names (``PhysicsWorld``, ``ChassisState``, ``apply_continuous``) load on first use, so
importing this package does not start pybullet (which also prints a banner on import).
"""

from smarts.core.errors import ActionError
from smarts.core.geometry import wrap_angle
from smarts.dynamics.action_spaces import (
    ACTION_COMPONENTS,
    ActionSpaceType,
    action_space,
    check_actions,
    lane_command,
)
from smarts.dynamics.bicycle import (
    bicycle_step,
    curvature_for_steering,
    steering_for_curvature,
    wheelbase_for_length,
)
from smarts.dynamics.lane_control import lane_control_step
from smarts.dynamics.limits import ReachLimits
from smarts.dynamics.pose_control import (
    apply_relative_pose,
    apply_target_pose,
    limit_relative_pose,
)

_PHYSICS_NAMES = ("PhysicsWorld", "ChassisState", "apply_continuous")


def __getattr__(name: str):
    if name in _PHYSICS_NAMES:
        from smarts.dynamics import pybullet_chassis

        return getattr(pybullet_chassis, name)
    raise AttributeError(f"module 'smarts.dynamics' has no attribute {name!r}")


__all__ = [
    "ACTION_COMPONENTS",
    "ActionError",
    "ActionSpaceType",
    "ChassisState",
    "PhysicsWorld",
    "ReachLimits",
    "action_space",
    "apply_continuous",
    "apply_relative_pose",
    "apply_target_pose",
    "bicycle_step",
    "check_actions",
    "curvature_for_steering",
    "lane_command",
    "lane_control_step",
    "limit_relative_pose",
    "steering_for_curvature",
    "wheelbase_for_length",
    "wrap_angle",
]
