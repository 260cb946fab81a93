"""Scenario copies stepped together by the batched backend, as plain arrays over *slots*.

Every learning agent of every copy is a slot (copies in order, agents in scenario order). A step
takes ``actions[slots, k]`` and gives per slot the observation, reward and end flags of the agent
that acted; copies whose agents have all finished are reset at once (auto-reset) and their first
observations are returned beside (``StepResult.first``), so no copy ever waits for another.
All copies of one step length form one simulation (``smarts.core.simulation``, one call per
stage) whatever their maps, events, rewards, action spaces and sensors; the env engine
(``smarts.env.driving``) adds social agents, V2V, observations and rewards, as it does for
``DrivingParallelEnv`` with one episode.

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

from smarts.core.errors import ActionError
from smarts.core.policies import PolicyResolver
from smarts.core.simulation import EpisodeSim, check_seed, derived_seed
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec
from smarts.env.batched.assembly import BatchedSetupError, check_batchable
from smarts.env.driving import Driving
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig

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


class _Group:
    """Copies stepped as one simulation (the env engine ``Driving``), and their slots."""

    def __init__(self, driving: Driving, copies: list[int], agent_slot: np.ndarray):
        self.driving, self.copies = driving, copies
        self.sim = driving.sim
        self.agent_slot = agent_slot  # slot of each agent (-1: a social agent, not a slot)
        self.learners = np.flatnonzero(agent_slot >= 0)
        self.learner_slots = agent_slot[self.learners]


class BatchedDriving:
    """``scenarios`` (names, YAML paths or specs; one copy each) stepped by the batched backend.

    ``observation``: one interface for every agent (None: the scenarios' own; the learners' must
    agree); ``reward_factory`` builds one task reward per simulation (``smarts.env.task_rewards``;
    None: each scenario's default reward); ``lane_relative`` and ``limits`` as for
    ``DrivingParallelEnv``; ``sim_device``: where simulation stages with a torch version run
    ("cpu": the compiled numpy kernels; "cuda", "torch-cpu": see
    ``smarts.dynamics.pose_control_torch.resolve_device``); ``policy_resolver`` turns social
    agents' locators into policies. Every copy of one step length is one simulation; what cannot
    share a process (SUMO) is refused with a ``BatchedSetupError`` naming the scenario and field.
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
        policy_resolver: PolicyResolver | None = None,
    ):
        if not scenarios:
            raise ValueError("BatchedDriving needs at least one scenario")
        self.specs = [as_spec(s) for s in scenarios]
        for spec in self.specs:
            check_batchable(spec)
        self.limits = limits or ReachLimits()
        self.slots: list[tuple[int, str]] = [(i, a.id) for i, s in enumerate(self.specs) for a in s.agents if not a.is_social]
        if not self.slots:
            raise BatchedSetupError(f"{self.specs[0].source}: every agent has a policy; at least one must learn")
        slot_index = {key: j for j, key in enumerate(self.slots)}
        by_step: dict[float, list[int]] = {}
        for i, spec in enumerate(self.specs):
            by_step.setdefault(spec.step_length, []).append(i)
        self.groups: list[_Group] = []
        self.copy_place: list[tuple[int, int]] = [(0, 0)] * len(self.specs)  # copy -> (group, episode)
        for copies in by_step.values():
            specs = [self.specs[i] for i in copies]
            driving = Driving(specs, observation=observation, limits=self.limits, lane_relative=lane_relative,
                              reward=reward_factory() if reward_factory else None, policy_resolver=policy_resolver,
                              device=sim_device)  # fmt: skip
            sim = driving.sim
            agent_slot = np.array([slot_index.get((copies[sim.agent_episode[a]], sim.local_agent_ids[a]), -1)
                                   for a in range(len(sim.agent_ids))], dtype=np.int64)  # fmt: skip
            g = len(self.groups)
            self.groups.append(_Group(driving, copies, agent_slot))
            for b, i in enumerate(copies):
                self.copy_place[i] = (g, b)
        self.action_space, self.observation_space = self._shared_spaces()
        n = len(self.slots)
        self._obs = {k: np.zeros((n, *s.shape), dtype=s.dtype) for k, s in self.observation_space.spaces.items()}
        self._first = {k: np.zeros_like(v) for k, v in self._obs.items()}
        self._next_seed: list[int | None] = [None] * len(self.specs)
        self._listeners: list[Callable[[], Any]] = []
        self.seed_schedule: Callable[[int], int | None] | None = None
        """When set, ``seed_schedule(copy)`` gives each new episode's seed instead (adapters with
        their own seeding convention)."""
        self._arange: np.ndarray | None = None

    def _shared_spaces(self) -> tuple[gym.spaces.Box | None, gym.spaces.Dict]:
        """The action space every slot shares (None when scenarios mix action spaces: then
        ``action_low``/``action_high`` bound each slot's columns) and the one observation space
        (a batch of observations is one array per key)."""
        g0 = self.groups[0]
        a0 = int(g0.learners[0])
        obs = g0.driving.observation_space(a0)
        first = self.specs[self.slots[0][0]]
        boxes: list[gym.spaces.Box] = [None] * len(self.slots)  # type: ignore[list-item]
        for g in self.groups:
            for a in g.learners.tolist():
                boxes[g.agent_slot[a]] = g.driving.action_space(a)
                if g.driving.observation_space(a) != obs:
                    copy, aid = self.slots[g.agent_slot[a]]
                    raise BatchedSetupError(
                        f"{self.specs[copy].source}: {aid}'s observation space differs from {first.source}'s "
                        f"{self.slots[0][1]}; give one interface (observation=...) for all"
                    )
        width = max(b.shape[0] for b in boxes)
        self.action_low = np.zeros((len(boxes), width), dtype=np.float32)
        self.action_high = np.zeros((len(boxes), width), dtype=np.float32)
        for j, box in enumerate(boxes):
            self.action_low[j, : box.shape[0]] = box.low
            self.action_high[j, : box.shape[0]] = box.high
        self.action_width = width
        """Columns of an action array (the widest slot's action; narrower ones read their first)."""
        shared = boxes[0] if all(b == boxes[0] for b in boxes) else None
        return shared, obs

    # ------------------------------------------------------------------ per-episode readers
    def episode_sim(self, copy: int) -> EpisodeSim:
        """Copy ``copy``'s current episode as a single simulation (its agents by their scenario
        ids), for per-episode readers such as the benchmark's ``EpisodeRecorder``."""
        g, b = self.copy_place[copy]
        return self.groups[g].sim.episode_sim(b)

    def add_step_listener(self, listener: Callable[[], Any]) -> None:
        """Call ``listener()`` after every step, before finished agents leave and finished copies
        restart (as ``DrivingParallelEnv.add_step_listener``: an ``EpisodeRecorder`` of each copy
        records its final step there; ``StepResult.restarted`` says which copies start anew)."""
        self._listeners.append(listener)

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
        """Reset ``episodes`` of ``group`` and write their learners' first observations into
        ``out``; returns those learners' slots."""
        seeds = [self._take_seed(group.copies[b]) for b in episodes.tolist()]
        agents, batches, _ = group.driving.reset(episodes, seeds)
        slots = np.zeros(0, dtype=np.int64)
        for members, obs in batches:
            keep = group.agent_slot[members] >= 0
            mine = group.agent_slot[members[keep]]
            for key, value in obs.items():
                out[key][mine] = value if keep.all() else value[keep]
            slots = np.concatenate([slots, mine])
        return slots

    def step(self, actions: np.ndarray) -> StepResult:
        """One step of every copy with ``actions[slot]`` (slots whose agent is not live are
        ignored); copies that end are reset before this returns."""
        actions = np.asarray(actions)
        n = len(self.slots)
        k = self.action_width
        if actions.ndim != 2 or actions.shape != (n, k):
            raise ActionError(f"actions: expected shape ({n}, {k}) (slots, action), got {actions.shape}", [])
        if actions.dtype.kind not in "fiu":
            raise ActionError(f"actions: expected real numbers, got dtype {actions.dtype}", [])
        reward = np.zeros(n, dtype=np.float32)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        acted = np.zeros(n, dtype=bool)
        restarted = np.zeros(n, dtype=bool)
        out = self._obs
        full = []
        for group in self.groups:
            arr = np.zeros((len(group.agent_slot), k), dtype=np.float64)
            arr[group.learners] = actions[group.learner_slots]
            if len(self.groups) > 1:
                group.driving.check_actions(arr)  # every group checks before any moves
            full.append(arr)
        for group, arr in zip(self.groups, full):
            res = group.driving.step(arr)
            slots = group.agent_slot[res.agents]
            for members, obs in res.batches:
                mine = group.agent_slot[members]
                if len(self.groups) == 1 and len(mine) == n and self._identity(mine):
                    out = obs  # every slot acted, in slot order: the built arrays are the result
                else:
                    for key, value in obs.items():
                        out[key][mine] = value
            reward[slots] = res.reward
            terminated[slots] = res.terminated
            truncated[slots] = res.truncated
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
