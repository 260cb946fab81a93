"""A PettingZoo ParallelEnv over the simulator: every agent acts each step.

Observations for all live agents are built in one batched pass (``ObservationBuilder``); the per-agent
dicts returned here are views into those batch arrays, so no per-agent work is done beyond the
dict itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from pettingzoo import ParallelEnv

from smarts.core.events import EVENT_NAMES, Event
from smarts.dynamics.action_spaces import ActionError, action_space
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec, build_simulation
from smarts.env.reward import default_rewards
from smarts.env.social import SocialAgents
from smarts.scenario import ScenarioSpec
from smarts.sensors.observation import ObservationBuilder, ObservationConfig


class DrivingParallelEnv(ParallelEnv):
    """Multi-agent driving in one scenario; agents are the scenario's agent ids (``agent_0``...)."""

    metadata = {"name": "smarts_driving_v0", "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scenario: str | Path | ScenarioSpec = "intersection_4way_left",
        *,
        observation: ObservationConfig | None = None,
        limits: ReachLimits | None = None,
        render_mode: str | None = None,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.scenario = as_spec(scenario)
        self.limits = limits or ReachLimits()
        self.sim = build_simulation(self.scenario, self.limits)
        self.builder = ObservationBuilder(observation)
        self.render_mode = render_mode
        self.social = SocialAgents(self.scenario, self.sim)
        self.possible_agents = [a for a, s in zip(self.sim.agent_ids, self.social.is_social) if not s]
        if not self.possible_agents:
            raise ValueError(f"{self.scenario.source}: every agent has a policy; at least one must learn")
        self.agents: list[str] = []
        self._obs_spaces = {a: self.builder.space for a in self.possible_agents}
        self._act_spaces = {
            a.id: action_space(a.action_space, self.limits, self.scenario.step_length)
            for a in self.scenario.agents
            if a.id in self.possible_agents
        }
        self._last: tuple[dict[str, np.ndarray], np.ndarray] | None = None  # for social agents
        self._renderer = None
        self._terminal_events = self.sim.event_config.terminate_on.copy()
        self._terminal_events[Event.MAX_STEPS] = False

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> gym.spaces.Dict:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> gym.spaces.Box:
        return self._act_spaces[agent]

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        self.sim.reset(seed if seed is not None else self.sim.seed)
        self.agents = list(self.possible_agents)
        agents = self.sim.active_agents
        batch = self.builder.build(self.sim, agents)
        self._last = (batch, agents)
        learners = ~self.social.is_social[agents]
        obs = self._split({k: v[learners] for k, v in batch.items()}, agents[learners])
        return obs, {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]):
        live = set(self.agents)
        unknown = [a for a in actions if a not in live]
        if unknown:
            raise ActionError(f"actions given for agents that are not live: {unknown}; live agents: {self.agents}", unknown)
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ActionError(f"no action given for live agents {missing}", missing)
        sim = self.sim
        if self.social.any:
            actions = {**actions, **self.social.actions(sim, *self._last)}
        sim.step(actions)
        agents = sim.active_agents
        batch = self.builder.build(sim, agents)
        if self.social.any:
            self._last = (batch, agents)
            learners = ~self.social.is_social[agents]
            batch = {k: v[learners] for k, v in batch.items()}
            agents = agents[learners]
        ids = [sim.agent_ids[i] for i in agents]
        obs = self._split(batch, agents)
        reward = default_rewards(sim, agents, self.scenario.reward)
        events = sim.agent_events[agents]
        done = sim.agent_done[agents]
        # Truncated: only the step limit ended the episode; terminated: a terminal event did.
        terminated = (events & self._terminal_events).any(axis=1)
        truncated = done & ~terminated
        infos: dict[str, dict] = {a: {} for a in ids}
        if events.any():
            for k in np.flatnonzero(events.any(axis=1)):
                infos[ids[k]]["events"] = [EVENT_NAMES[e] for e in np.flatnonzero(events[k])]
        sim.remove_done_agents()
        self.agents = [a for a, d in zip(ids, done.tolist()) if not d]
        return (
            obs,
            dict(zip(ids, reward.tolist())),
            dict(zip(ids, terminated.tolist())),
            dict(zip(ids, truncated.tolist())),
            infos,
        )

    def _split(self, batch: dict[str, np.ndarray], agents: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
        """Per-agent dicts of row views into the batch arrays (iterating an array is the cheap way
        to get its row views)."""
        ids = self.sim.agent_ids
        keys = list(batch)
        per_agent = zip(*[list(v) for v in batch.values()])
        return {ids[i]: dict(zip(keys, values)) for i, values in zip(agents.tolist(), per_agent)}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'; nothing is drawn")
            return None
        if self._renderer is None:
            from smarts.sensors.topdown import TopDownRenderer

            self._renderer = TopDownRenderer(self.sim.road_map)
        return self._renderer.render(self.sim)

    def close(self) -> None:
        self.sim.close()
