"""The action spaces an agent can drive with, their gymnasium boxes and input checking.

Each action is one row of a float array ``[n_agents, k]``. A non-finite number, a value that is
not a real number (bool, complex, text) or a wrongly shaped array is an error (it would corrupt the vehicle state); a finite number outside the box is not: the
controllers limit it to what the car can do (pose spaces, see ``pose_control``) or clip it to the
box (continuous and lane spaces), so a policy exploring outside its box still drives a real car.
"""

from __future__ import annotations

from enum import Enum
from typing import Sequence

import gymnasium
import numpy as np

from smarts.core.errors import ActionError
from smarts.core.spec.scenario import CONTROLLERS  # noqa: F401  (how actions reach the action space)
from smarts.dynamics.limits import ReachLimits

# Bounds of the world-frame target position, m: large enough for any map, small enough for float32.
WORLD_BOUND = 1.0e5


class ActionSpaceType(str, Enum):
    RELATIVE_TARGET_POSE = "relative_target_pose"  # (dx forward, dy left, dheading) vehicle frame
    TARGET_POSE = "target_pose"  # (x, y, heading) world frame
    CONTINUOUS = "continuous"  # (throttle [0,1], brake [0,1], steering [-1,1], +1 = full left)
    LANE = "lane"  # (target_speed m/s, lane_change -1 right / 0 keep / +1 left)


ACTION_COMPONENTS: dict[ActionSpaceType, tuple[str, ...]] = {
    ActionSpaceType.RELATIVE_TARGET_POSE: ("dx", "dy", "dheading"),
    ActionSpaceType.TARGET_POSE: ("x", "y", "heading"),
    ActionSpaceType.CONTINUOUS: ("throttle", "brake", "steering"),
    ActionSpaceType.LANE: ("target_speed", "lane_change"),
}


LANE_RELATIVE_COMPONENTS = ("speed", "lane_change")


def _as_kind(kind: ActionSpaceType | str) -> ActionSpaceType:
    try:
        return ActionSpaceType(kind)
    except ValueError:
        names = ", ".join(repr(k.value) for k in ActionSpaceType)
        raise ValueError(f"unknown action space {kind!r}; expected one of {names}") from None


def action_space(kind: ActionSpaceType | str, limits: ReachLimits, dt: float) -> gymnasium.spaces.Box:
    """The float32 box of one agent's action for ``kind``.

    The relative pose box is what the car could at most cover in ``dt`` seconds (|dx|, |dy| <=
    max_speed*dt, |dheading| <= max_yaw_rate*dt); a negative dx asks to stop (or to reverse when the
    limits allow it).
    """
    kind = _as_kind(kind)
    if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
        raise ValueError(f"action_space: dt must be a positive number of seconds, got {dt!r}")
    if kind is ActionSpaceType.RELATIVE_TARGET_POSE:
        step = limits.max_speed * dt
        high = [step, step, limits.max_yaw_rate * dt]
        low = [-h for h in high]
    elif kind is ActionSpaceType.TARGET_POSE:
        high = [WORLD_BOUND, WORLD_BOUND, np.pi]
        low = [-h for h in high]
    elif kind is ActionSpaceType.CONTINUOUS:
        low, high = [0.0, 0.0, -1.0], [1.0, 1.0, 1.0]
    else:
        low, high = [0.0, -1.0], [limits.max_speed, 1.0]
    return gymnasium.spaces.Box(
        low=np.asarray(low, dtype=np.float32),
        high=np.asarray(high, dtype=np.float32),
        dtype=np.float32,
    )


def agent_action_space(
    kind: ActionSpaceType | str, controller: str, limits: ReachLimits, dt: float
) -> gymnasium.spaces.Box:
    """The box an agent acts in: its action space's own, or the lane-relative command box
    ``[-1, 1]^2`` (speed, lane_change) when its controller is ``lane_relative``."""
    box = action_space(kind, limits, dt)
    if controller == "direct":
        return box
    if controller != "lane_relative":
        raise ValueError(f"unknown controller {controller!r}; expected one of {', '.join(CONTROLLERS)}")
    return gymnasium.spaces.Box(low=-1.0, high=1.0, shape=(2,), dtype=np.float32)


def check_actions(
    kind: ActionSpaceType | str,
    actions: np.ndarray,
    agent_ids: Sequence[str],
    controller: str = "direct",
) -> np.ndarray:
    """Check an ``[n_agents, k]`` action array and return it as float64.

    Raises ``ActionError`` naming the agents and components for a wrong shape or non-finite values.
    Finite values outside the box pass: the controllers limit them.
    """
    kind = _as_kind(kind)
    components = action_components(kind, controller)
    kind_label = action_label(kind, controller)
    try:
        arr = np.asarray(actions)
        if arr.dtype.kind not in REAL_KINDS:
            raise TypeError(f"dtype {arr.dtype}")
        arr = arr.astype(np.float64, copy=False)
    except (TypeError, ValueError) as exc:
        raise ActionError(
            f"{kind_label} actions for agents {list(agent_ids)} are not numbers ({exc}); "
            f"expected a float array of shape ({len(agent_ids)}, {len(components)})",
            agent_ids,
        ) from None
    expected = (len(agent_ids), len(components))
    if arr.shape != expected:
        if arr.ndim == 2 and arr.shape[0] == len(agent_ids):
            raise ActionError(
                f"{', '.join(agent_ids)}: {kind_label} action has {arr.shape[1]} components; "
                f"expected {len(components)} ({', '.join(components)})",
                agent_ids,
            )
        raise ActionError(
            f"{kind_label} actions have shape {arr.shape}; expected {expected}: one row of "
            f"({', '.join(components)}) per agent {list(agent_ids)}",
            agent_ids,
        )
    finite = np.isfinite(arr)
    if finite.all():
        return arr
    bad_rows, bad_cols = np.nonzero(~finite)
    problems = [
        f"{agent_ids[r]}: {kind_label} action component {components[c]} is {arr[r, c]}"
        for r, c in zip(bad_rows.tolist(), bad_cols.tolist())
    ]
    bad_agents = list(dict.fromkeys(agent_ids[r] for r in bad_rows.tolist()))
    raise ActionError("; ".join(problems) + "; expected finite numbers", bad_agents)


REAL_KINDS = "iuf"
"""numpy dtype kinds an action may have: integers and floats (not bool, complex, str, object)."""


def action_components(kind: ActionSpaceType | str, controller: str = "direct") -> tuple[str, ...]:
    """Names of the components of one action: the space's own, or the lane-relative command's."""
    return ACTION_COMPONENTS[_as_kind(kind)] if controller == "direct" else LANE_RELATIVE_COMPONENTS


def action_label(kind: ActionSpaceType | str, controller: str = "direct") -> str:
    """How messages name an action space: ``continuous``, ``relative_target_pose (lane_relative)``."""
    kind = _as_kind(kind)
    return kind.value if controller == "direct" else f"{kind.value} ({controller})"


def action_problem(kind: ActionSpaceType | str, value: object, agent_id: str, controller: str = "direct") -> str | None:
    """What is wrong with one agent's action ``value`` (one row), or None when it can be applied.

    The message names the agent, the space (and controller) and what was expected.
    """
    kind = _as_kind(kind)
    components = action_components(kind, controller)
    label = action_label(kind, controller)
    expected = f"expected {len(components)} real numbers ({', '.join(components)})"
    try:
        arr = np.asarray(value)
    except Exception as exc:  # an object numpy cannot even look at
        return f"{agent_id}: {label} action of type {type(value).__name__} is not numbers ({exc}); {expected}"
    if arr.dtype.kind not in REAL_KINDS:
        what = {"b": "booleans", "c": "complex numbers"}.get(arr.dtype.kind, "not numbers")
        return f"{agent_id}: {label} action {_short(value)} is {what} (dtype {arr.dtype}); {expected}"
    if arr.shape != (len(components),):
        if arr.ndim == 1:
            return f"{agent_id}: {label} action has {arr.shape[0]} components; expected {len(components)} ({', '.join(components)})"
        return f"{agent_id}: {label} action has shape {arr.shape}; expected shape ({len(components)},): ({', '.join(components)})"
    finite = np.isfinite(arr)
    if finite.all():
        return None
    bad = np.flatnonzero(~finite).tolist()
    return (
        "; ".join(f"{agent_id}: {label} action component {components[c]} is {arr[c]}" for c in bad)
        + "; expected finite numbers"
    )


def _short(value: object, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def lane_command(actions: np.ndarray, limits: ReachLimits) -> tuple[np.ndarray, np.ndarray]:
    """Split lane actions into target speed (clipped to [0, max_speed]) and lane change.

    The lane change is rounded to -1 (right), 0 (keep) or +1 (left); halves round to even (keep).
    """
    target_speed = np.clip(actions[:, 0], 0.0, limits.max_speed)
    lane_change = np.rint(np.clip(actions[:, 1], -1.0, 1.0)).astype(np.int8)
    return target_speed, lane_change
