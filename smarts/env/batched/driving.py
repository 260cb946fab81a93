"""Scenario copies stepped together by the batched backend, as plain arrays over *slots*.

Every learning agent of every copy is a slot (copies in order, agents in scenario order). A step
takes ``actions[slots, k]`` and gives per slot the observation, reward and end flags of the agent
that acted; copies whose agents have all finished are reset at once (auto-reset) and their first
observations are returned beside (``StepResult.first``), so no copy ever waits for another.
All copies form one ``BatchedSimulation`` (one call per stage), whatever their maps; only copies
that cannot share one (another step length or event set, or another reward section when no task
reward is given) form further ones.

Seeds are those of ``SmartsBatchedEnv``: after ``set_seed(s)`` copy ``i`` starts at seed
``s + i * 100_003`` and counts up by one per episode, so both backends play the same episodes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from smarts.core.batched import BatchedSimulation, EpisodeSim
from smarts.core.events import Event
from smarts.core.simulation import check_seed, derived_seed
from smarts.dynamics.action_spaces import agent_action_space
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec
from smarts.env.batched.assembly import BatchedSetupError, build_batched_simulation, check_batchable
from smarts.env.batched.observe import BatchedObserver
from smarts.env.reward import default_rewards
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig, as_interface

COPY_SEED_STRIDE = 100_003
"""Seed distance between copies after ``set_seed`` (as ``SmartsBatchedEnv``)."""

__all__ = ["BatchedDriving", "BatchedSetupError", "StepResult"]


@dataclass
class StepResult:
    """One step of every slot (arrays over slots)."""

    obs: dict[str, np.ndarray]  # observation after the step (zeros for slots that did not act);
    # valid until the next step
    reward: np.ndarray  # float32[S]
    terminated: np.ndarray  # bool[S] a terminal event ended the slot's agent
    truncated: np.ndarray  # bool[S] the step limit ended it
    acted: np.ndarray  # bool[S] the slot's agent took part in this step
    restarted: np.ndarray  # bool[S] the slot's copy was reset after this step
    first: dict[str, np.ndarray]  # first observation of the new episode where ``restarted``


class _StepView:
    """The batch as a reward function sees it: ``step_count`` per asked agent (its episode's)."""

    def __init__(self, sim: BatchedSimulation, agents: np.ndarray):
        self._sim = sim
        self.step_count = sim.episode_step[sim.agent_episode[agents]]

    def __getattr__(self, name: str):
        return getattr(self._sim, name)


class _Group:
    """Copies stepped as one ``BatchedSimulation``, with its reward function and its slots."""

    def __init__(self, sim: BatchedSimulation, copies: list[int], reward, reward_spec, agent_slot: np.ndarray):
        self.sim, self.copies, self.reward, self.reward_spec = sim, copies, reward, reward_spec
        self.agent_slot = agent_slot  # slot of each union agent
        # Events that end an agent as terminated (the step limit truncates): the group's own set.
        self.terminal = sim.event_config.terminate_on.copy()
        self.terminal[Event.MAX_STEPS] = False


class BatchedDriving:
    """``scenarios`` (names, YAML paths or specs; one copy each) stepped by the batched backend.

    ``observation``: one interface for every agent (None: the scenarios' own, which must agree);
    ``reward_factory`` builds one task reward per group (``smarts.env.task_rewards``; None:
    each scenario's default reward); ``lane_relative`` and ``limits`` as for ``DrivingParallelEnv``;
    ``sim_device``: where simulation stages with a torch version run ("cpu": the compiled numpy
    kernels; "cuda", "torch-cpu": see ``smarts.dynamics.pose_control_torch.resolve_device``).
    Refuses what it cannot batch (SUMO traffic, social agents, comms, Continuous...) with a
    ``BatchedSetupError`` naming the scenario and field.
    """

    render_mode = None  # nothing is drawn (vector-env wrappers ask)

    def __init__(
        self,
        scenarios: Sequence[str | Path | ScenarioSpec],
        *,
        observation: AgentInterface | ObservationConfig | None = None,
        limits: ReachLimits | None = None,
        lane_relative: LaneRelativeParams | None = None,
        reward_factory: Callable[[], Any] | None = None,
        sim_device: str = "cpu",
    ):
        if not scenarios:
            raise ValueError("BatchedDriving needs at least one scenario")
        self.specs = [as_spec(s) for s in scenarios]
        for spec in self.specs:
            check_batchable(spec)
        self.interface = self._interface(observation)
        self.observer = BatchedObserver(self.interface)
        self.limits = limits or ReachLimits()
        first = self.specs[0]
        agent0 = first.agents[0]
        self.action_space = agent_action_space(agent0.action_space, agent0.controller, self.limits, first.step_length)
        self.observation_space: gym.spaces.Dict = self.observer.space
        self.slots: list[tuple[int, str]] = [(i, a.id) for i, s in enumerate(self.specs) for a in s.agents]
        slot_index = {key: j for j, key in enumerate(self.slots)}
        by_kind: dict[tuple, list[int]] = {}
        for i, spec in enumerate(self.specs):
            reward_key = None if reward_factory is not None else repr(spec.reward)
            by_kind.setdefault((spec.step_length, repr(spec.events), reward_key), []).append(i)
        self.groups: list[_Group] = []
        self.copy_place: list[tuple[int, int]] = [(0, 0)] * len(self.specs)  # copy -> (group, episode)
        for copies in by_kind.values():
            specs = [self.specs[i] for i in copies]
            sim = build_batched_simulation(specs, [s.seed for s in specs], limits=self.limits,
                                           lane_relative=lane_relative, device=sim_device)  # fmt: skip
            agent_slot = np.array([slot_index[(copies[sim.agent_episode[a]], sim.local_agent_ids[a])]
                                   for a in range(len(sim.agent_ids))], dtype=np.int64)  # fmt: skip
            g = len(self.groups)
            self.groups.append(_Group(sim, copies, reward_factory() if reward_factory else None, specs[0].reward, agent_slot))
            for b, i in enumerate(copies):
                self.copy_place[i] = (g, b)
        for spec in self.specs:
            for agent in spec.agents:
                box = agent_action_space(agent.action_space, agent.controller, self.limits, spec.step_length)
                if box != self.action_space:
                    raise BatchedSetupError(
                        f"{spec.source}: {agent.id}'s action space {box} differs from {first.source}'s "
                        f"{agent0.id} ({self.action_space}); batched scenarios share one"
                    )
        n = len(self.slots)
        self._obs = {k: np.zeros((n, *s.shape), dtype=s.dtype) for k, s in self.observation_space.spaces.items()}
        self._first = {k: np.zeros_like(v) for k, v in self._obs.items()}
        self._arange: np.ndarray | None = None
        self._next_seed: list[int | None] = [None] * len(self.specs)
        self._listeners: list[Callable[[], Any]] = []
        self.seed_schedule: Callable[[int], int | None] | None = None
        """When set, ``seed_schedule(copy)`` gives each new episode's seed instead (adapters with
        their own seeding convention)."""

    # ------------------------------------------------------------------ per-episode readers
    def episode_sim(self, copy: int) -> EpisodeSim:
        """Copy ``copy``'s current episode as a single simulation (its agents by their scenario
        ids), for per-episode readers such as the benchmark's ``EpisodeRecorder``."""
        g, b = self.copy_place[copy]
        return EpisodeSim(self.groups[g].sim, b)

    def add_step_listener(self, listener: Callable[[], Any]) -> None:
        """Call ``listener()`` after every step, before finished agents leave and finished copies
        restart (as ``DrivingParallelEnv.add_step_listener``: an ``EpisodeRecorder`` of each copy
        records its final step there; ``StepResult.restarted`` says which copies start anew)."""
        self._listeners.append(listener)

    def _interface(self, observation) -> AgentInterface:
        if observation is not None:
            return as_interface(observation)
        found = {a.interface or AgentInterface() for s in self.specs for a in s.agents}
        if len(found) != 1:
            raise BatchedSetupError(
                f"{self.specs[0].source}: the scenarios' agents have different observation interfaces; "
                "give one interface (observation=...) for all"
            )
        return found.pop()

    # ------------------------------------------------------------------ seeding
    @property
    def num_slots(self) -> int:
        return len(self.slots)

    def set_seed(self, seed: int | None) -> None:
        """Copy ``i`` starts at seed ``seed + i * 100_003`` and counts up per episode (None: each
        copy replays its scenario's seed)."""
        if seed is not None:
            seed = check_seed(seed, "BatchedDriving.set_seed(seed)")
        self._next_seed = [None if seed is None else derived_seed(seed, i * COPY_SEED_STRIDE) for i in range(len(self.specs))]

    def _take_seed(self, copy: int) -> int | None:
        if self.seed_schedule is not None:
            return self.seed_schedule(copy)
        seed = self._next_seed[copy]
        if seed is not None:
            self._next_seed[copy] = derived_seed(seed, 1)
        return seed

    # ------------------------------------------------------------------ episodes
    def reset(self) -> dict[str, np.ndarray]:
        """Start every copy; returns the first observation of every slot."""
        for v in self._obs.values():
            v[:] = 0
        for group in self.groups:
            episodes = np.arange(group.sim.episodes, dtype=np.int64)
            self._restart(group, episodes, self._obs)
        return self._obs

    def _restart(self, group: _Group, episodes: np.ndarray, out: dict[str, np.ndarray]) -> np.ndarray:
        """Reset ``episodes`` of ``group`` and write their agents' first observations into ``out``;
        returns those agents' slots."""
        sim = group.sim
        seeds = [self._take_seed(group.copies[b]) for b in episodes.tolist()]
        sim.reset_episodes(episodes, seeds)
        agents = sim.active_agents[np.isin(sim.agent_episode[sim.active_agents], episodes)]
        obs = self.observer.build(sim, agents)
        slots = group.agent_slot[agents]
        for key, value in obs.items():
            out[key][slots] = value
        return slots

    def step(self, actions: np.ndarray) -> StepResult:
        """One step of every copy with ``actions[slot]`` (slots whose agent is not live are
        ignored); copies that end are reset before this returns."""
        actions = np.asarray(actions)
        n = len(self.slots)
        if actions.ndim != 2 or actions.shape[0] != n:
            raise ValueError(f"actions: expected shape ({n}, {self.action_space.shape[0]}) (slots, action), got {actions.shape}")
        reward = np.zeros(n, dtype=np.float32)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        acted = np.zeros(n, dtype=bool)
        restarted = np.zeros(n, dtype=bool)
        out = self._obs
        stepped = []
        for group in self.groups:
            sim = group.sim
            group_actions = actions[group.agent_slot]
            if not np.isfinite(group_actions[sim.active_agents]).all():
                sim.check_actions(group_actions)  # raises ActionError naming the agents
            stepped.append(group_actions)
        for group, group_actions in zip(self.groups, stepped):
            sim = group.sim
            sim.step(group_actions)
            agents = sim.active_agents
            slots = group.agent_slot[agents]
            obs = self.observer.build(sim, agents)
            if len(self.groups) == 1 and len(slots) == n and self._identity(slots):
                out = obs  # every slot acted, in slot order: the built arrays are the result
            else:
                for key, value in obs.items():
                    out[key][slots] = value
            if group.reward is not None:
                r = group.reward(_StepView(sim, agents), agents)
            else:
                r = default_rewards(sim, agents, group.reward_spec)
            events = sim.agent_events[agents]
            done = sim.agent_done[agents]
            term = (events & group.terminal).any(axis=1)
            reward[slots] = r
            terminated[slots] = term
            truncated[slots] = done & ~term
            acted[slots] = True
        for listener in self._listeners:
            listener()  # sees this step's state before finished agents leave
        for group in self.groups:
            sim = group.sim
            sim.remove_done_agents()
            over = sim.episodes_over()
            if over.size:
                restarted[self._restart(group, over, self._first)] = True
        if out is self._obs and not acted.all():
            for v in out.values():
                v[~acted] = 0
        return StepResult(out, reward, terminated, truncated, acted, restarted, self._first)

    def _identity(self, slots: np.ndarray) -> bool:
        if self._arange is None or len(self._arange) != len(slots):
            self._arange = np.arange(len(slots))
        return bool((slots == self._arange).all())

    def close(self) -> None:
        for group in self.groups:
            group.sim.close()
