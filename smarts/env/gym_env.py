"""A single-agent Gymnasium env: one agent of a scenario, the others removed.

With comms on, the agent hears connected traffic (and sends into the void: no other agent is left).

Registered as ``smarts/Driving-v0``; ``gymnasium.make("smarts/Driving-v0", scenario=...)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from smarts.core.simulation import check_seed
from smarts.core.spec import replace
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec
from smarts.env.parallel_env import DrivingParallelEnv
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig


class DrivingEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scenario: str | Path | ScenarioSpec = "straight_2lane_cruise",
        *,
        agent: str | None = None,
        observation: AgentInterface | ObservationConfig | None = None,
        limits: ReachLimits | None = None,
        render_mode: str | None = None,
        render_view: str = "map",
    ):
        """``observation`` overrides the agent's interface from the scenario; ``render_view`` is
        ``map`` or ``ego`` (the agent's ego-centred view)."""
        spec = as_spec(scenario)
        ids = [a.id for a in spec.agents]
        agent = ids[0] if agent is None else agent
        if agent not in ids:
            raise ValueError(f"{spec.source}: scenario has no agent {agent!r}; agents: {ids}")
        comms = spec.comms
        if comms is not None and comms.agent_channels:  # channels of the removed agents go too
            kept = {a: c for a, c in comms.agent_channels.items() if a == agent}
            comms = replace(comms, agent_channels=kept)
        spec = replace(spec, agents=[a for a in spec.agents if a.id == agent], comms=comms)
        self.agent = agent
        self.env = DrivingParallelEnv(
            spec, observation=observation, limits=limits, render_mode=render_mode, render_view=render_view
        )
        self.observation_space = self.env.observation_space(agent)
        self.action_space = self.env.action_space(agent)
        self.render_mode = render_mode

    @property
    def sim(self):
        return self.env.sim

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """``seed``: an integer from 0 to 2**64 - 1 (numpy integers too), else ``ValueError``
        naming it; None keeps the last one (first the scenario's)."""
        if seed is not None:
            seed = check_seed(seed, "DrivingEnv.reset(seed=...)")
        super().reset(seed=seed)
        obs, infos = self.env.reset(seed=seed, options=options)
        return obs[self.agent], infos[self.agent]

    def step(self, action: Any):
        obs, rewards, terms, truncs, infos = self.env.step({self.agent: np.asarray(action)})
        a = self.agent
        return obs[a], float(rewards[a]), bool(terms[a]), bool(truncs[a]), infos[a]

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()
