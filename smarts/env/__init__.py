"""Environments over the simulator: PettingZoo (multi-agent) and Gymnasium (single agent)."""

import gymnasium

from smarts.env.gym_env import DrivingEnv
from smarts.env.parallel_env import DrivingParallelEnv

GYM_ID = "smarts/Driving-v0"
if GYM_ID not in gymnasium.registry:
    gymnasium.register(id=GYM_ID, entry_point="smarts.env.gym_env:DrivingEnv")

__all__ = ["DrivingEnv", "DrivingParallelEnv", "GYM_ID"]
