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
from smarts.core.events import EVENT_NAMES, Event
from smarts.core.policies import PolicyResolver
from smarts.core.simulation import check_seed
from smarts.dynamics.action_spaces import agent_action_space
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec, build_simulation
from smarts.env.reward import RewardFunction, default_rewards
from smarts.env.social import SocialAgents
from smarts.env.v2v import V2VLink
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig, as_interface
from smarts.sensors.suite import Batch, ObservationSuite

ObservationOption = AgentInterface | ObservationConfig
RENDER_VIEWS = ("map", "ego")


class DrivingParallelEnv(ParallelEnv):
    """Multi-agent driving in one scenario; agents are the scenario's agent ids (``agent_0``...)."""

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
        self.limits = limits or ReachLimits()
        self.sim = build_simulation(self.scenario, self.limits, lane_relative=lane_relative)
        self.reward_fn = reward
        self.sensors = ObservationSuite(self._interfaces(observation))
        self.builder = self.sensors.builders[0]  # the only one when all agents share an interface
        self.render_mode = render_mode
        self.render_view = render_view
        self._ego_renderer = None
        self.social = SocialAgents(self.scenario, self.sim, policy_resolver)
        self.possible_agents = [a for a, s in zip(self.sim.agent_ids, self.social.is_social) if not s]
        if not self.possible_agents:
            raise ValueError(f"{self.scenario.source}: every agent has a policy; at least one must learn")
        self.agents: list[str] = []
        driving = [
            agent_action_space(a.action_space, a.controller, self.limits, self.scenario.step_length)
            for a in self.scenario.agents
        ]
        self.comms: V2VLink | None = None
        self._comms_spaces: dict[int, gym.spaces.Dict] = {}
        if self.scenario.comms is not None:
            self.comms = V2VLink(self.scenario.comms, self.sim, [box.shape[0] for box in driving])
        self._obs_spaces = {a: self._observation_space(self.sim.agent_index[a]) for a in self.possible_agents}
        self._act_spaces = {
            a.id: box if self.comms is None else self.comms.action_space(box)
            for a, box in zip(self.scenario.agents, driving)
            if a.id in self.possible_agents
        }
        self._live = np.zeros(0, dtype=np.int64)  # agent indices of ``self.agents``
        self._last: list[Batch] = []  # for social agents
        self._renderer = None
        self._step_listeners: list = []
        self._terminal_events = self.sim.event_config.terminate_on.copy()
        self._terminal_events[Event.MAX_STEPS] = False
        if render_view not in RENDER_VIEWS and not (
            render_view.startswith("ego:") and render_view[4:] in self.sim.agent_index
        ):
            raise ValueError(
                f"render_view must be 'map', 'ego' or 'ego:<agent id>' with an agent of the scenario "
                f"({', '.join(self.sim.agent_ids)}), got {render_view!r}"
            )

    def _interfaces(self, observation) -> list[AgentInterface]:
        """Each agent's interface: the scenario's, unless ``observation`` overrides it."""
        spec_agents = self.scenario.agents
        chosen = [a.interface or AgentInterface() for a in spec_agents]
        if observation is None:
            return chosen
        if isinstance(observation, Mapping):
            unknown = [k for k in observation if k not in self.scenario.agent_ids]
            if unknown:
                raise ValueError(f"observation: no agents {unknown} in the scenario; agents: {self.scenario.agent_ids}")
            return [as_interface(observation[a.id]) if a.id in observation else c for a, c in zip(spec_agents, chosen)]
        return [as_interface(observation)] * len(spec_agents)

    def _observation_space(self, agent: int) -> gym.spaces.Dict:
        """The agent's sensor space, plus the received messages with comms on (one object per
        interface group, so agents of a group share it)."""
        space = self.sensors.space(agent)
        if self.comms is None:
            return space
        if id(space) not in self._comms_spaces:
            self._comms_spaces[id(space)] = self.comms.observation_space(space)
        return self._comms_spaces[id(space)]

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
        sim.reset(sim.seed if seed is None else check_seed(seed, "DrivingParallelEnv.reset(seed=...)"))
        self.agents = list(self.possible_agents)
        self._live = np.array([sim.agent_index[a] for a in self.agents], dtype=np.int64)
        agents = sim.active_agents
        batches = self.sensors.build(sim, agents)
        infos: dict[str, dict] = {a: {} for a in self.agents}
        if self.comms is not None:
            received = self.comms.reset(sim)
            self.comms.merge(batches, agents, received)
            self._count_messages(infos, received.count, agents)
        self._last = batches
        obs = self._split(self._learners(batches) if self.social.any else batches)
        return obs, infos

    def check_actions(self, actions: Mapping[str, Any]) -> None:
        """Raise the ``ActionError`` that ``step(actions)`` would raise, changing nothing (a batch
        of env copies checks every copy before stepping any)."""
        self._checked(actions, full=True)

    def _checked(self, actions: Mapping[str, Any], full: bool) -> tuple[dict, np.ndarray | None, np.ndarray | None]:
        """The learners' driving actions, message payloads and channels; raises ``ActionError``
        for unknown or missing agents and malformed messages. ``full`` (or social agents, whose
        policies must not run on a step that is then refused) also checks the driving actions;
        otherwise ``Simulation.step`` checks them, still before anything moves."""
        live = set(self.agents)
        unknown = [a for a in actions if a not in live]
        if unknown:
            raise ActionError(f"actions given for agents that are not live: {unknown}; live agents: {self.agents}", unknown)
        if len(actions) != len(live):
            missing = [a for a in self.agents if a not in actions]
            raise ActionError(f"no action given for live agents {missing}", missing)
        payloads = channels = None
        if self.comms is not None:  # social agents send nothing
            actions, payloads, channels = self.comms.split(actions, self.agents, self._live)
        if full or self.social.any:
            self.sim.check_actions(actions, self._live)
        return actions, payloads, channels

    def step(self, actions: dict[str, Any]):
        """One step of every live agent. Atomic: a missing, unknown or malformed action raises
        ``ActionError`` naming the agents and what was expected, and changes nothing (vehicles,
        controllers, traffic, messages, clock, step count and the next observation are as if the
        call had not been made)."""
        sim = self.sim
        comms = self.comms
        actions, payloads, channels = self._checked(actions, full=False)
        senders = self._live
        if self.social.any:
            actions = dict(actions)
            for members, batch in self._last:
                actions.update(self.social.actions(sim, batch, members))
        sim.step(actions)
        agents = sim.active_agents
        batches = self.sensors.build(sim, agents)
        if comms is not None:
            received = comms.exchange(sim, senders, payloads, channels)
            comms.merge(batches, agents, received)
        if self.social.any:
            self._last = batches
            batches = self._learners(batches)
            agents = agents[~self.social.is_social[agents]]
        ids = [sim.agent_ids[i] for i in agents]
        obs = self._split(batches)
        if self.reward_fn is None:
            reward = default_rewards(sim, agents, self.scenario.reward)
        else:
            reward = self.reward_fn(sim, agents)
        events = sim.agent_events[agents]
        done = sim.agent_done[agents]
        # Truncated: only the step limit ended the episode; terminated: a terminal event did.
        terminated = (events & self._terminal_events).any(axis=1)
        truncated = done & ~terminated
        infos: dict[str, dict] = {a: {} for a in ids}
        if events.any():
            for k in np.flatnonzero(events.any(axis=1)):
                infos[ids[k]]["events"] = [EVENT_NAMES[e] for e in np.flatnonzero(events[k])]
        if comms is not None:
            self._count_messages(infos, received.count, sim.active_agents)
        for listener in self._step_listeners:
            listener(sim)  # sees this step's state before finished agents leave the table
        sim.remove_done_agents()
        if done.any():
            self.agents = [a for a, d in zip(ids, done.tolist()) if not d]
            self._live = agents[~done]
        else:
            self.agents = ids
            self._live = agents
        return (
            obs,
            dict(zip(ids, reward.tolist())),
            dict(zip(ids, terminated.tolist())),
            dict(zip(ids, truncated.tolist())),
            infos,
        )

    def add_step_listener(self, listener) -> None:
        """Call ``listener(sim)`` after every step, before agents that finished are removed (the
        benchmark's episode recorder uses this to log the final step of every agent)."""
        self._step_listeners.append(listener)

    def _count_messages(self, infos: dict[str, dict], count: np.ndarray, agents: np.ndarray) -> None:
        """``info["messages_received"]`` of each learner; ``count`` is in the order of ``agents``."""
        if self.social.any:
            count = count[~self.social.is_social[agents]]
        for info, n in zip(infos.values(), count.tolist()):
            info["messages_received"] = n

    def _learners(self, batches: list[Batch]) -> list[Batch]:
        """The batches without the social agents' rows."""
        out = []
        for members, batch in batches:
            keep = ~self.social.is_social[members]
            if keep.all():
                out.append((members, batch))
            elif keep.any():
                out.append((members[keep], {k: v[keep] for k, v in batch.items()}))
        return out

    def _split(self, batches: list[Batch]) -> dict[str, dict[str, np.ndarray]]:
        """Per-agent dicts of row views into the batch arrays (iterating an array is the cheap way
        to get its row views)."""
        ids = self.sim.agent_ids
        out: dict[str, dict[str, np.ndarray]] = {}
        for agents, batch in batches:
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
