"""Environments over the simulator: PettingZoo (multi-agent) and Gymnasium (single agent).

``DrivingEnv`` and ``DrivingParallelEnv`` are imported on first use, so that importing one light
module of this package (``smarts.env.task_rewards`` for a config's reward weights, say) does not
build the whole simulator stack; ``smarts/Driving-v0`` is registered with Gymnasium on import.
"""

from typing import TYPE_CHECKING

import gymnasium

if TYPE_CHECKING:
    from smarts.env.gym_env import DrivingEnv
    from smarts.env.parallel_env import DrivingParallelEnv

GYM_ID = "smarts/Driving-v0"
if GYM_ID not in gymnasium.registry:
    gymnasium.register(id=GYM_ID, entry_point="smarts.env.gym_env:DrivingEnv")

__all__ = ["DrivingEnv", "DrivingParallelEnv", "GYM_ID"]


def __getattr__(name: str):
    if name == "DrivingEnv":
        from smarts.env.gym_env import DrivingEnv

        return DrivingEnv
    if name == "DrivingParallelEnv":
        from smarts.env.parallel_env import DrivingParallelEnv

        return DrivingParallelEnv
    raise AttributeError(f"module 'smarts.env' has no attribute {name!r}")
