"""The env step over one simulation of B episodes: what every env of this package is a view of.

``Driving`` owns the simulation (``smarts.core.simulation``) of some scenarios' episodes and does,
for every agent of every episode at once: the social agents' actions (each policy called once for
all its agents), the message part of the actions and the V2V exchange (each episode's own
network: no message crosses episodes), the step, the observations (one batched pass per interface
group), the rewards and the end flags. ``DrivingParallelEnv`` is a view of one episode (B = 1) with
actions and observations by agent id; ``BatchedDriving`` is the same engine over many episodes with
arrays over slots and auto-reset.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from smarts.comms import Received
from smarts.compiled import njit
from smarts.core.errors import ActionError
from smarts.core.events import NUM_EVENTS, Event
from smarts.core.policies import PolicyResolver
from smarts.dynamics.action_spaces import REAL_KINDS, agent_action_space
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec, build_simulation
from smarts.env.reward import RewardFunction, default_rewards, reward_weights
from smarts.env.social import SocialAgents
from smarts.env.v2v import V2VLink
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig, as_interface
from smarts.sensors.suite import Batch, ObservationSuite

ObservationOption = AgentInterface | ObservationConfig


@dataclass
class StepOut:
    """One step of the learning agents that acted (``agents``, ascending agent indices)."""

    agents: np.ndarray
    batches: list[Batch]  # their observations after the step, per interface group
    reward: np.ndarray  # float64[n]
    terminated: np.ndarray  # bool[n] a terminal event ended the agent
    truncated: np.ndarray  # bool[n] only the step limit ended it
    events: np.ndarray  # bool[n, NUM_EVENTS]
    messages: np.ndarray | None  # int64[n] messages received (None without comms)


class Driving:
    """``specs`` (one episode each) on one simulation.

    ``observation``: one interface for every agent, a mapping agent id -> interface (one episode),
    or None (each agent's own from its scenario). ``reward``: a task reward ``reward(sim,
    agents)`` for every agent (``smarts.env.task_rewards``), or None: each scenario's default reward.
    ``seeds``: the episodes' first seeds (default: each scenario's). ``device``: where stages
    with a torch version run. ``policy_resolver``: turns social agents' locators into policies.
    """

    def __init__(
        self,
        specs: Sequence[str | Path | ScenarioSpec],
        *,
        observation: ObservationOption | Mapping[str, ObservationOption] | None = None,
        limits: ReachLimits | None = None,
        lane_relative: LaneRelativeParams | None = None,
        reward: RewardFunction | None = None,
        policy_resolver: PolicyResolver | None = None,
        seeds: Sequence[int] | None = None,
        device: str = "cpu",
    ):
        self.specs = [as_spec(s) for s in specs]
        self.limits = limits or ReachLimits()
        self.sim = sim = build_simulation(
            self.specs, self.limits, lane_relative=lane_relative, seeds=seeds, device=device
        )
        interfaces = self._interfaces(observation)
        with_comms = [self.specs[b].comms is not None for b in sim.agent_episode.tolist()]
        self.sensors = ObservationSuite(interfaces, [(i, c) for i, c in zip(interfaces, with_comms)], sim.agent_episode)
        self.social = SocialAgents(self.specs, sim, policy_resolver)
        self.learner = ~self.social.is_social
        self.reward_fn = reward
        self._weights = reward_weights([self.specs[b].reward for b in sim.agent_episode.tolist()])
        self._one_reward = bool((self._weights == self._weights[:, :1]).all())
        if self._one_reward:  # every agent's weights are the same: one column (no gathering)
            self._weights = np.ascontiguousarray(self._weights[:, :1])
        self.terminal = sim.terminate_on.copy()
        self.terminal[:, Event.MAX_STEPS] = False
        self._one_rule = bool((self.terminal == self.terminal[:1]).all())
        self._rules = self.terminal[:1] if self._one_rule else self.terminal  # what ``_ends`` reads
        self.driving_spaces = [
            agent_action_space(a.action_space, a.controller, self.limits, spec.step_length)
            for spec in self.specs for a in spec.agents
        ]  # fmt: skip
        """Each agent's driving action space (its action without the message part)."""
        self.driving_width = np.array([box.shape[0] for box in self.driving_spaces], dtype=np.int64)
        by_config: dict = {}
        for b, spec in enumerate(self.specs):
            if spec.comms is not None:
                by_config.setdefault(spec.comms, []).append(b)
        self.v2v = [V2VLink(config, sim, episodes, self.driving_width) for config, episodes in by_config.items()]
        """One link per distinct comms setting, each serving all its episodes at once."""
        self.links: list[V2VLink | None] = [None] * len(self.specs)  # by episode
        for link in self.v2v:
            for b in link.episodes.tolist():
                self.links[b] = link
        self.comms = bool(self.v2v)
        self.hears = np.array(with_comms, dtype=bool)  # per agent: its episode has V2V
        self._social_obs: dict[str, np.ndarray] = {}  # last observation of every social agent, by agent
        self._listeners: list = []

    # ------------------------------------------------------------------ construction
    def _interfaces(self, observation) -> list[AgentInterface]:
        chosen = [a.interface or AgentInterface() for spec in self.specs for a in spec.agents]
        if observation is None:
            return chosen
        if isinstance(observation, Mapping):
            if len(self.specs) != 1:
                raise ValueError("observation: a mapping by agent id needs a single scenario")
            ids = self.specs[0].agent_ids
            unknown = [k for k in observation if k not in ids]
            if unknown:
                raise ValueError(f"observation: no agents {unknown} in the scenario; agents: {ids}")
            return [as_interface(observation[a]) if a in observation else c for a, c in zip(ids, chosen)]
        return [as_interface(observation)] * len(chosen)

    def action_space(self, agent: int) -> gym.spaces.Box:
        """Agent ``agent``'s whole action space (driving, then the message part with comms)."""
        box = self.driving_spaces[agent]
        link = self.links[int(self.sim.agent_episode[agent])]
        return box if link is None else link.action_space(box)

    def observation_space(self, agent: int) -> gym.spaces.Dict:
        space = self.sensors.space(agent)
        link = self.links[int(self.sim.agent_episode[agent])]
        return space if link is None else link.observation_space(space)

    # ------------------------------------------------------------------ episodes
    def add_step_listener(self, listener) -> None:
        """Call ``listener(sim)`` after every step, before agents that finished are removed."""
        self._listeners.append(listener)

    def reset(
        self, episodes: np.ndarray, seeds: Sequence[int | None] | None = None
    ) -> tuple[np.ndarray, list[Batch], np.ndarray | None]:
        """Start ``episodes``; returns their agents (learners and social, ascending), the agents'
        first observations and, with comms, the messages each heard."""
        sim = self.sim
        episodes = np.asarray(episodes, dtype=np.int64)
        sim.reset_episodes(episodes, seeds)
        agents = sim.active_agents[np.isin(sim.agent_episode[sim.active_agents], episodes)]
        batches = self.sensors.build(sim, agents)
        count = None
        if self.comms:
            parts = []
            for link in self.v2v:
                mine = episodes[np.isin(episodes, link.episodes)]
                if mine.size:
                    hearing = agents[np.isin(sim.agent_episode[agents], mine)]
                    parts.append((hearing, link.reset(mine)))
            count = self._merge(batches, agents, parts)
        if self.social.any:
            self._keep_social(batches)
        return agents, batches, count

    def step(self, actions) -> StepOut:
        """One step of every episode. ``actions``: by agent id (the live learners, each its whole
        action), or an array whose row ``a`` is agent ``a``'s whole action (rows of social agents
        and finished agents are ignored). Atomic: a refused action changes nothing."""
        sim = self.sim
        active = sim.active_agents
        social = self.social.any
        senders = active[self.learner[active]] if social else active
        driving, payloads, channels = self._split(actions, senders) if self.comms else (actions, None, None)
        if social:
            driving = self._as_wide_as_any(driving)
            sim.check_actions(driving, senders)  # the policies must not run on a refused step
            driving = self._with_social(driving, active)
        sim.step(driving)
        agents = sim.active_agents
        batches = self.sensors.build(sim, agents)
        count = None
        if self.comms:
            parts = [link.exchange(*self._sent(link, senders, payloads, channels)) for link in self.v2v]
            count = self._merge(batches, agents, parts)
        if social:
            self._keep_social(batches)
            keep = self.learner[agents]
            batches = learner_batches(batches, self.learner)
            agents = agents[keep]
            count = None if count is None else count[keep]
        if self.reward_fn is not None:
            reward = self.reward_fn(sim, agents)
        else:
            reward = default_rewards(sim, agents, self._weights if self._one_reward else self._weights[:, agents])
        events = np.empty((len(agents), NUM_EVENTS), dtype=bool)
        ends = np.empty((2, len(agents)), dtype=bool)
        _ends(sim.agent_events, sim.agent_done, agents, self._rules, sim.agent_episode, events, ends)
        terminated, truncated = ends[0], ends[1]
        for listener in self._listeners:
            listener(sim)  # sees this step's state before finished agents leave the table
        return StepOut(agents, batches, reward, terminated, truncated, events, count)

    def close(self) -> None:
        self.sim.close()

    # ------------------------------------------------------------------ actions
    def check_actions(self, actions) -> None:
        """Raise the ``ActionError`` that ``step(actions)`` would raise, changing nothing."""
        sim = self.sim
        active = sim.active_agents
        senders = active[self.learner[active]]
        driving, _, _ = self._split(actions, senders)
        sim.check_actions(driving, senders)

    def _split(self, actions, senders: np.ndarray):
        """The driving actions (dict or array, as given) and, with comms, each link's senders'
        payloads and channels; a malformed message raises ``ActionError`` before anything moves."""
        if not self.comms:
            return actions, None, None
        sim = self.sim
        payloads, channels = {}, {}
        if isinstance(actions, np.ndarray):
            if actions.ndim != 2 or actions.shape[0] != len(sim.agent_ids) or actions.dtype.kind not in REAL_KINDS:
                raise ActionError(
                    f"expected a real-number action array of {len(sim.agent_ids)} rows, got {actions.shape} {actions.dtype}",
                    [],
                )
            for k, link in enumerate(self.v2v):
                mine = senders[link.mine[senders]]
                payloads[k], channels[k] = link.split_array(actions, mine)
            return actions, payloads, channels
        driving = dict(actions)
        for k, link in enumerate(self.v2v):
            mine = senders[link.mine[senders]]
            ids = [sim.agent_ids[a] for a in mine.tolist()]
            missing = [a for a in ids if a not in actions]
            if missing:
                raise ActionError(f"no action given for live agents {missing}", missing)
            control, payloads[k], channels[k] = link.split(actions, ids, mine)
            driving.update(control)
        return driving, payloads, channels

    def _sent(self, link: V2VLink, senders: np.ndarray, payloads: dict, channels: dict) -> tuple:
        k = self.v2v.index(link)
        return senders[link.mine[senders]], payloads[k], channels[k]

    def _merge(self, batches: list[Batch], agents: np.ndarray, parts: list[tuple[np.ndarray, Received]]) -> np.ndarray:
        """Add each link's received messages (``parts``: its receivers, ascending, and what they
        got) to the batches of agents whose episodes have V2V; returns each agent's message count
        (0 without V2V), in the order of ``agents``."""
        count = np.zeros(len(agents), dtype=np.int64)
        parts = [(r, got) for r, got in parts if len(r)]
        if not parts:
            return count
        if len(parts) == 1:
            hearing, received = parts[0]
        else:
            hearing = np.concatenate([r for r, _ in parts])
            order = np.argsort(hearing, kind="stable")
            hearing = hearing[order]
            received = Received(
                *(np.concatenate([getattr(got, f) for _, got in parts])[order] for f in Received._fields)
            )
        if hearing.size == agents.size:
            V2VLink.merge(batches, agents, received)
            return received.count
        V2VLink.merge([(m, b) for m, b in batches if self.hears[m[0]]], hearing, received)
        count[np.isin(agents, hearing)] = received.count
        return count

    def _as_wide_as_any(self, driving):
        """An array of the learners' actions padded to the widest action of any agent: a social
        agent's action (filled in after the check) may be wider than every learner's."""
        width = int(self.driving_width.max()) if len(self.driving_width) else 0
        if isinstance(driving, np.ndarray) and driving.ndim == 2 and driving.shape[1] < width:
            full = np.zeros((driving.shape[0], width), dtype=np.float64)
            full[:, : driving.shape[1]] = driving
            return full
        return driving

    def _with_social(self, driving, active: np.ndarray):
        """The learners' actions with the live social agents' own (from their last observations)."""
        sim = self.sim
        social = active[~self.learner[active]]
        acts = self.social.actions_of(social, self._social_obs)
        if isinstance(driving, np.ndarray):
            width = max(driving.shape[1], acts.shape[1] if len(acts) else 0)
            full = np.zeros((driving.shape[0], width), dtype=np.float64)
            full[:, : driving.shape[1]] = driving
            full[social, : acts.shape[1]] = acts
            return full
        out = dict(driving)
        out.update((sim.agent_ids[a], act) for a, act in zip(social.tolist(), acts))
        return out

    def _keep_social(self, batches: list[Batch]) -> None:
        """Remember the social agents' observations for their next actions."""
        for members, batch in batches:
            social = members[~self.learner[members]]
            if social.size == 0:
                continue
            at = ~self.learner[members]
            for key, value in batch.items():
                store = self._social_obs.get(key)
                if store is None or store.shape[1:] != value.shape[1:]:
                    store = self._social_obs[key] = np.zeros((len(self.learner), *value.shape[1:]), dtype=value.dtype)
                store[social] = value[at]


def _by_episode(sim, agents: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """``agents`` (ascending) grouped by episode, in episode order."""
    if agents.size == 0:
        return []
    episode = sim.agent_episode[agents]
    cuts = np.flatnonzero(np.diff(episode)) + 1
    return [(int(episode[g[0]]), agents[g]) for g in np.split(np.arange(len(agents)), cuts)]


@njit(nogil=True)
def _ends(events, done, agents, rules, agent_episode, out_events, out):  # pragma: no cover - compiled
    """``out_events[i]``: the events of agent ``agents[i]``; ``out[0, i]``: it had a terminal
    event (``rules``: of its episode, or one row for all); ``out[1, i]``: it is done without one
    (the step limit, the map's end). One compiled pass: at one agent the numpy version of these
    cost as much as the reward."""
    per_episode = rules.shape[0] > 1
    for i in range(agents.shape[0]):
        a = agents[i]
        rule = rules[agent_episode[a] if per_episode else 0]
        hit = False
        for e in range(events.shape[1]):
            out_events[i, e] = events[a, e]
            hit |= events[a, e] and rule[e]
        out[0, i] = hit
        out[1, i] = done[a] and not hit


def learner_batches(batches: list[Batch], learner: np.ndarray) -> list[Batch]:
    """The batches without the social agents' rows."""
    out = []
    for members, batch in batches:
        keep = learner[members]
        if keep.all():
            out.append((members, batch))
        elif keep.any():
            out.append((members[keep], {k: v[keep] for k, v in batch.items()}))
    return out
