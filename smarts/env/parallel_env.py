"""A PettingZoo ParallelEnv over the simulator: every agent acts each step.

Observations for all live agents are built in one batched pass per interface group
(``ObservationSuite``: agents with equal ``AgentInterface`` share a space and a pass); the
per-agent dicts returned here are views into those batch arrays, so no per-agent work is done
beyond the dict itself.

With a scenario ``comms`` section, actions carry a message part after the driving part and
observations hold the messages received (``smarts.env.v2v``); without one, spaces are unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from pettingzoo import ParallelEnv

from smarts.core.errors import ActionError
from smarts.core.events import EVENT_NAMES
from smarts.core.policies import PolicyResolver
from smarts.core.simulation import check_seed
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec
from smarts.env.driving import Driving, learner_batches
from smarts.env.reward import RewardFunction
from smarts.env.v2v import V2VLink
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig
from smarts.sensors.suite import Batch

ObservationOption = AgentInterface | ObservationConfig
RENDER_VIEWS = ("map", "ego")
SMALL_BATCH = 4
"""Up to this many agents in a batch, ``_split`` indexes each row (cheaper than iterating arrays)."""


class DrivingParallelEnv(ParallelEnv):
    """Multi-agent driving in one scenario; agents are the scenario's agent ids (``agent_0``...).

    A view of one episode of the env engine (``smarts.env.driving.Driving`` over a simulation of
    B = 1 episodes), with actions and observations by agent id."""

    metadata = {"name": "smarts_driving_v0", "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scenario: str | Path | ScenarioSpec = "intersection_4way_left",
        *,
        observation: ObservationOption | Mapping[str, ObservationOption] | None = None,
        limits: ReachLimits | None = None,
        render_mode: str | None = None,
        render_view: str = "map",
        lane_relative: LaneRelativeParams | None = None,
        reward: RewardFunction | None = None,
        policy_resolver: PolicyResolver | None = None,
    ):
        """``observation`` overrides the scenario's agent interfaces: one interface (or the basic
        ``ObservationConfig``) for every agent, or a mapping from agent id to one. ``render_view``
        is ``map`` (the whole map), ``ego`` (centred on the first live agent) or ``ego:<agent
        id>``. ``lane_relative`` sets how lane-relative commands drive (agents with
        ``controller: lane_relative``); ``reward`` replaces the scenario's default reward with a
        task reward (``smarts.env.task_rewards``); ``policy_resolver`` turns the social agents'
        ``policy`` locators into policies (``smarts.core.policies``; None: the installed default,
        the zoo)."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.scenario = as_spec(scenario)
        self.driving = Driving(
            [self.scenario], observation=observation, limits=limits, lane_relative=lane_relative, reward=reward,
            policy_resolver=policy_resolver,
        )  # fmt: skip
        self.limits = self.driving.limits
        self.sim = self.driving.sim
        self.reward_fn = reward
        self.sensors = self.driving.sensors
        self.builder = self.sensors.builders[0]  # the only one when all agents share an interface
        self.social = self.driving.social
        self.comms: V2VLink | None = self.driving.links[0]  # the episode's V2V link (None without comms)
        self.render_mode = render_mode
        self.render_view = render_view
        self._ego_renderer = None
        self.possible_agents = [a for a, s in zip(self.sim.agent_ids, self.social.is_social) if not s]
        if not self.possible_agents:
            raise ValueError(f"{self.scenario.source}: every agent has a policy; at least one must learn")
        self.agents: list[str] = []
        index = self.sim.agent_index
        self._obs_spaces = {a: self.driving.observation_space(index[a]) for a in self.possible_agents}
        self._act_spaces = {a: self.driving.action_space(index[a]) for a in self.possible_agents}
        self._live = np.zeros(0, dtype=np.int64)  # agent indices of ``self.agents``
        self._ids_of: tuple[np.ndarray | None, list[str]] = (None, [])  # (agents, their ids)
        self._renderer = None
        self._started = False
        if render_view not in RENDER_VIEWS and not (
            render_view.startswith("ego:") and render_view[4:] in self.sim.agent_index
        ):
            raise ValueError(
                f"render_view must be 'map', 'ego' or 'ego:<agent id>' with an agent of the scenario "
                f"({', '.join(self.sim.agent_ids)}), got {render_view!r}"
            )

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> gym.spaces.Dict:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> gym.spaces.Box:
        return self._act_spaces[agent]

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Start an episode with ``seed`` (None: the last one, first the scenario's): an integer
        from 0 to 2**64 - 1, else ``ValueError`` naming it."""
        sim = self.sim
        seed = sim.seed if seed is None else check_seed(seed, "DrivingParallelEnv.reset(seed=...)")
        agents, batches, count = self.driving.reset(np.zeros(1, dtype=np.int64), [seed])
        self.agents = list(self.possible_agents)
        self._live = np.array([sim.agent_index[a] for a in self.agents], dtype=np.int64)
        self._started = True
        infos: dict[str, dict] = {a: {} for a in self.agents}
        if count is not None:
            self._count_messages(infos, count, agents)
        obs = self._split(learner_batches(batches, self.driving.learner) if self.social.any else batches)
        return obs, infos

    def check_actions(self, actions: Mapping[str, Any]) -> None:
        """Raise the ``ActionError`` that ``step(actions)`` would raise, changing nothing (a batch
        of env copies checks every copy before stepping any)."""
        self._check_agents(actions)
        self.driving.check_actions(actions)

    def _check_agents(self, actions: Mapping[str, Any]) -> None:
        """``ActionError`` for actions of agents that are not live, or live agents without one."""
        if not self._started:
            raise RuntimeError("DrivingParallelEnv.step() before reset(): call reset() first")
        if len(actions) == len(self.agents) and all(a in actions for a in self.agents):
            return  # one action per live agent: nothing unknown, nothing missing
        live = set(self.agents)
        unknown = [a for a in actions if a not in live]
        if unknown:
            raise ActionError(
                f"actions given for agents that are not live: {unknown}; live agents: {self.agents}", unknown
            )
        missing = [a for a in self.agents if a not in actions]
        raise ActionError(f"no action given for live agents {missing}", missing)

    def step(self, actions: dict[str, Any]):
        """One step of every live agent. Atomic: a missing, unknown or malformed action raises
        ``ActionError`` naming the agents and what was expected, and changes nothing (vehicles,
        controllers, traffic, messages, clock, step count and the next observation are as if the
        call had not been made)."""
        self._check_agents(actions)
        out = self.driving.step(actions)
        agents = out.agents
        ids = self._ids(agents)
        obs = self._split(out.batches)
        infos: dict[str, dict] = {a: {} for a in ids}
        events = out.events
        if events.any():
            for k in np.flatnonzero(events.any(axis=1)):
                infos[ids[k]]["events"] = [EVENT_NAMES[e] for e in np.flatnonzero(events[k])]
        if out.messages is not None:
            for info, n in zip(infos.values(), out.messages.tolist()):
                info["messages_received"] = n
        self.sim.remove_done_agents()
        terminated, truncated = out.terminated.tolist(), out.truncated.tolist()
        if any(terminated) or any(truncated):
            done = out.terminated | out.truncated
            self.agents = [a for a, d in zip(ids, done.tolist()) if not d]
            self._live = agents[~done]
        else:
            self.agents = ids
            self._live = agents
        return obs, dict(zip(ids, out.reward.tolist())), dict(zip(ids, terminated)), dict(zip(ids, truncated)), infos

    def _ids(self, agents: np.ndarray) -> list[str]:
        """The ids of ``agents`` (kept while the simulation hands out the same active-agent array)."""
        if self._ids_of[0] is not agents:
            self._ids_of = (agents, [self.sim.agent_ids[i] for i in agents.tolist()])
        return list(self._ids_of[1])

    def add_step_listener(self, listener) -> None:
        """Call ``listener(sim)`` after every step, before agents that finished are removed (the
        benchmark's episode recorder uses this to log the final step of every agent)."""
        self.driving.add_step_listener(listener)

    def _count_messages(self, infos: dict[str, dict], count: np.ndarray, agents: np.ndarray) -> None:
        """``info["messages_received"]`` of each learner; ``count`` is in the order of ``agents``."""
        if self.social.any:
            count = count[self.driving.learner[agents]]
        for info, n in zip(infos.values(), count.tolist()):
            info["messages_received"] = n

    def _split(self, batches: list[Batch]) -> dict[str, dict[str, np.ndarray]]:
        """Per-agent dicts of row views into the batch arrays (for a few agents each row view is
        taken by index; for more, iterating an array is the cheap way to get its row views)."""
        ids = self.sim.agent_ids
        out: dict[str, dict[str, np.ndarray]] = {}
        for agents, batch in batches:
            if len(agents) <= SMALL_BATCH:
                for k, i in enumerate(agents.tolist()):
                    out[ids[i]] = {key: value[k] for key, value in batch.items()}
                continue
            keys = list(batch)
            per_agent = zip(*[list(v) for v in batch.values()])
            out.update((ids[i], dict(zip(keys, values))) for i, values in zip(agents.tolist(), per_agent))
        return out

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode='rgb_array'; nothing is drawn")
            return None
        if self.render_view != "map":
            follow = self._followed_agent()
            if follow is not None:
                if self._ego_renderer is None:
                    from smarts.sensors.rasters import EgoViewRenderer

                    self._ego_renderer = EgoViewRenderer()
                return self._ego_renderer.render(self.sim, follow)
        if self._renderer is None:
            from smarts.sensors.topdown import TopDownRenderer

            self._renderer = TopDownRenderer(self.sim.road_map)
        return self._renderer.render(self.sim)

    def _followed_agent(self) -> int | None:
        """Agent index the ego view follows; None (the map view) once it has left."""
        index = self.sim.agent_index
        name = self.render_view[4:] if self.render_view.startswith("ego:") else (self.agents or [None])[0]
        if name is None or not self.sim.agent_active[index[name]]:
            return None
        return index[name]

    def close(self) -> None:
        self.sim.close()
