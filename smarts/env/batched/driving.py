"""Scenario copies stepped together by the batched backend, as plain arrays over *slots*.

Every learning agent of every copy is a slot (copies in order, agents in scenario order). A step
takes ``actions[slots, k]`` and gives per slot the observation, reward and end flags of the agent
that acted; copies whose agents have all finished are reset at once (auto-reset) and their first
observations are returned beside (``StepResult.first``), so no copy ever waits for another.
All copies of one step length form one simulation (``smarts.core.simulation``, one call per
stage) whatever their maps, events, rewards, action spaces and sensors; the env engine
(``smarts.env.driving``) adds social agents, V2V, observations and rewards, as it does for
``DrivingParallelEnv`` with one episode.

Seeds (the one rule of every adapter over this env): after ``set_seed(s)`` copy ``i`` starts at
seed ``s + i * 100_003`` and counts up by one per episode; ``reset(seeds)`` starts each copy at a
given seed instead.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from smarts.core.errors import ActionError, ScenarioError, WorkerError
from smarts.core.policies import PolicyResolver
from smarts.core.simulation import EpisodeSim, check_seed, derived_seed
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.env.assembly import as_spec
from smarts.env.driving import Driving
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationConfig


class BatchedSetupError(ScenarioError):
    """Scenarios (or options) that cannot be batched together; the message says what differs."""


COPY_SEED_STRIDE = 100_003
"""Seed distance between copies after ``set_seed``."""

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
    agents' locators into policies. Every copy of one step length in this process is one
    simulation. ``workers`` > 0 spreads the copies over that many worker processes instead (each
    one simulation of its share); a SUMO copy always runs in a worker process of its own, as one
    simulation of one episode (libsumo holds one simulation per process), stepped while this
    process steps the rest. ``copy_ids``: the copies' numbers in a larger batch (their seeds), for
    workers.
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
        workers: int = 0,
        copy_ids: Sequence[int] | None = None,
        in_worker: bool = False,
    ):
        if not scenarios:
            raise ValueError("BatchedDriving needs at least one scenario")
        self.specs = [as_spec(s) for s in scenarios]
        self.limits = limits or ReachLimits()
        self.copy_ids = list(range(len(self.specs))) if copy_ids is None else list(copy_ids)
        self.slots: list[tuple[int, str]] = [
            (i, a.id) for i, s in enumerate(self.specs) for a in s.agents if not a.is_social
        ]
        if not self.slots:
            raise BatchedSetupError(f"{self.specs[0].source}: every agent has a policy; at least one must learn")
        slot_index = {key: j for j, key in enumerate(self.slots)}
        sumo = [i for i, spec in enumerate(self.specs) if is_sumo(spec)]
        rest = [i for i in range(len(self.specs)) if i not in sumo]
        if in_worker and len(self.specs) == 1:
            sumo, rest = [], [0]  # a worker's one SUMO copy runs here
        if workers < 0:
            raise ValueError(f"workers: expected 0 (every copy in this process) or more, got {workers}")
        local = [] if workers else rest
        shard_copies = [share.tolist() for share in np.array_split(np.array(rest, dtype=np.int64), workers)
                         if len(share)] if workers else []  # fmt: skip
        # Contiguous shares: a worker's slots are one block of rows of the shared buffer (the copies
        # cycle through the scenarios, so blocks mix them as an interleaved split would).
        shard_copies += [[i] for i in sumo]  # libsumo holds one simulation per process
        options = dict(observation=observation, limits=self.limits, lane_relative=lane_relative,
                       reward_factory=reward_factory, sim_device=sim_device, policy_resolver=policy_resolver)  # fmt: skip
        self.shards = [_Shard(self, copies, options, [slot_index[k] for k in self.slots if k[0] in copies])
                       for copies in shard_copies]  # fmt: skip
        by_step: dict[float, list[int]] = {}
        for i in local:
            by_step.setdefault(self.specs[i].step_length, []).append(i)
        self.groups: list[_Group] = []
        self.copy_place: list[tuple[int, int] | None] = [None] * len(self.specs)  # copy -> (group, episode)
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
        for shard in self.shards:
            shard.started()
        self.action_space, self.observation_space = self._shared_spaces()
        n = len(self.slots)
        self._buffer: SharedArrays | None = None
        if self.shards:  # one block every worker writes its rows into and this process reads
            self._buffer = SharedArrays(step_layout(self.observation_space, n, self.action_width))
            for shard in self.shards:
                shard.attach(self._buffer)
            self._obs = self._buffer.group("obs")
            self._first = self._buffer.group("first")
        else:
            self._obs = {k: np.zeros((n, *s.shape), dtype=s.dtype) for k, s in self.observation_space.spaces.items()}
            self._first = {k: np.zeros_like(v) for k, v in self._obs.items()}
        self._next_seed: list[int | None] = [None] * len(self.specs)
        self._listeners: list[Callable[[], Any]] = []
        self._arange: np.ndarray | None = None
        self._started = False  # stepping before the first reset is refused (nothing would move)
        self._part_shards = self._split_shards()
        self.parts: list[slice | np.ndarray] = (
            [_rows(np.sort(np.concatenate([s.slots for s in shards]))) for shards in self._part_shards]
            if self._part_shards
            else [slice(0, n)]
        )
        """Slots that can step apart (``begin_step``/``end_step``), as rows of the slot arrays."""
        self._part_sizes = [len(np.arange(n)[rows]) for rows in self.parts]
        self._stepping: list[np.ndarray | None] = [None] * len(self.parts)  # actions of parts begun

    def _shared_spaces(self) -> tuple[gym.spaces.Box | None, gym.spaces.Dict]:
        """The action space every slot shares (None when scenarios mix action spaces: then
        ``action_low``/``action_high`` bound each slot's columns) and the one observation space
        (a batch of observations is one array per key)."""
        first = self.specs[self.slots[0][0]]
        boxes: list[gym.spaces.Box] = [None] * len(self.slots)  # type: ignore[list-item]
        spaces: list[gym.spaces.Dict] = [None] * len(self.slots)  # type: ignore[list-item]
        for g in self.groups:
            for a in g.learners.tolist():
                boxes[g.agent_slot[a]] = g.driving.action_space(a)
                spaces[g.agent_slot[a]] = g.driving.observation_space(a)
        for shard in self.shards:
            for j, box, space in zip(shard.slots, shard.boxes, shard.spaces):
                boxes[j], spaces[j] = box, space
        obs = spaces[0]
        for j, space in enumerate(spaces):
            if space != obs:
                copy, aid = self.slots[j]
                raise BatchedSetupError(
                    f"{self.specs[copy].source}: {aid}'s observation space differs from {first.source}'s "
                    f"{self.slots[0][1]} ({_space_difference(obs, space)}); give one interface (observation=...) "
                    "and one V2V setting (a comms section, or none) for all"
                )
        width = max(b.shape[0] for b in boxes)
        self.action_low = np.zeros((len(boxes), width), dtype=np.float32)
        self.action_high = np.zeros((len(boxes), width), dtype=np.float32)
        for j, box in enumerate(boxes):
            self.action_low[j, : box.shape[0]] = box.low
            self.action_high[j, : box.shape[0]] = box.high
        self.action_width = width
        """Columns of an action array (the widest slot's action; narrower ones read their first)."""
        self.slot_action_spaces = boxes
        """Each slot's own action space."""
        shared = boxes[0] if all(b == boxes[0] for b in boxes) else None
        return shared, obs

    # ------------------------------------------------------------------ per-episode readers
    def episode_sim(self, copy: int) -> EpisodeSim:
        """Copy ``copy``'s current episode as a single simulation (its agents by their scenario
        ids), for per-episode readers such as the benchmark's ``EpisodeRecorder``."""
        if self.copy_place[copy] is None:
            raise ValueError(
                f"copy {copy} ({self.specs[copy].source}) runs in a worker process; its episodes are read there"
            )
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
        self._next_seed = [None if seed is None else derived_seed(seed, i * COPY_SEED_STRIDE) for i in self.copy_ids]
        for shard in self.shards:
            shard.call("seed", seed)

    def _take_seed(self, copy: int) -> int | None:
        seed = self._next_seed[copy]
        if seed is not None:
            self._next_seed[copy] = derived_seed(seed, 1)
        return seed

    # ------------------------------------------------------------------ episodes
    def reset(self, seeds: Sequence[int] | None = None) -> dict[str, np.ndarray]:
        """Start every copy (copy ``i`` with ``seeds[i]`` when given; its later episodes count up
        from there); returns the first observation of every slot."""
        if seeds is not None:
            if len(seeds) != len(self.specs):
                raise ValueError(f"seeds: expected {len(self.specs)} seeds (one per copy), got {len(seeds)}")
            self._next_seed = [check_seed(s, f"seeds[{i}]") for i, s in enumerate(seeds)]
        self._check_idle("reset")
        for v in self._obs.values():
            v[:] = 0
        for shard in self.shards:
            shard.send("reset", None if seeds is None else [self._next_seed[i] for i in shard.copies])
        for group in self.groups:
            episodes = np.arange(group.sim.episodes, dtype=np.int64)
            self._restart(group, episodes, self._obs)
        for shard in self.shards:
            shard.receive()  # its first observations are in the shared rows
        self._started = True
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
        if not self._started:
            raise RuntimeError("BatchedDriving.step() before reset(): call reset() first")
        self._check_idle("step")
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
        if self.shards:  # the workers step while this process steps its own copies
            for shard in self.shards:
                shard.check(actions)  # a worker's refusal must come before anything moves
            self._buffer.arrays["actions"][:, :k] = actions
            for shard in self.shards:
                shard.send("step", None)
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
                if len(self.groups) == 1 and not self.shards and len(mine) == n and self._identity(mine):
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
        if self.shards:
            for shard in self.shards:
                shard.receive()  # its rows of the shared buffer now hold its step
            flags = self._buffer.arrays
            for shard in self.shards:
                j = shard.rows
                reward[j], terminated[j], truncated[j] = (
                    flags["reward"][j],
                    flags["terminated"][j],
                    flags["truncated"][j],
                )
                acted[j], restarted[j] = flags["acted"][j], flags["restarted"][j]
        if out is self._obs and not acted.all():
            for v in out.values():
                v[~acted] = 0
        return StepResult(out, reward, terminated, truncated, acted, restarted, self._first)

    # ------------------------------------------------------------------ stepping in parts
    def _split_shards(self) -> list[list[_Shard]]:
        """The workers of each part: with every copy in worker processes and at least two of them,
        the first and the second half of the workers, so a caller can act for one half while the
        other steps; else none (all slots are one part, stepped by ``step``)."""
        if self.groups or len(self.shards) < 2:
            return []
        half = len(self.shards) // 2
        return [self.shards[:half], self.shards[half:]]

    def begin_step(self, actions: np.ndarray, part: int) -> None:
        """Start the step of the slots of ``parts[part]`` with their actions (``actions[i]`` for
        the part's ``i``-th slot); ``end_step(part)`` waits for it. The parts step in turn, each
        once per step, so every copy sees the same steps as with ``step``; with one part this is
        ``step`` split in two."""
        if self._stepping[part] is not None:
            raise RuntimeError(f"BatchedDriving.begin_step: part {part} is already stepping; end_step({part}) first")
        actions = np.asarray(actions)
        if len(self.parts) == 1:
            self._stepping[part] = actions  # stepped by end_step
            return
        if not self._started:
            raise RuntimeError("BatchedDriving.begin_step() before reset(): call reset() first")
        rows, k, count = self.parts[part], self.action_width, self._part_sizes[part]
        if actions.ndim != 2 or actions.shape != (count, k):
            raise ActionError(f"actions of part {part}: expected shape ({count}, {k}) (its slots, action), got "
                              f"{actions.shape}", [])  # fmt: skip
        if actions.dtype.kind not in "fiu":
            raise ActionError(f"actions: expected real numbers, got dtype {actions.dtype}", [])
        shards = self._part_shards[part]
        whole = self._buffer.arrays["actions"]
        whole[rows, :k] = actions
        for shard in shards:
            shard.check(whole[:, :k])  # every worker of the part checks before any of them moves
        for shard in shards:
            shard.send("step", None)
        self._stepping[part] = actions

    def end_step(self, part: int) -> StepResult:
        """Wait for the step ``begin_step(..., part)`` began; its results over the part's slots
        (observations in place in the shared buffer, valid until the part's next step)."""
        actions, self._stepping[part] = self._stepping[part], None
        if actions is None:
            raise RuntimeError(f"BatchedDriving.end_step: part {part} was not begun; call begin_step first")
        if len(self.parts) == 1:
            return self.step(actions)
        for shard in self._part_shards[part]:
            shard.receive()  # its rows of the shared buffer now hold its step
        rows, flags = self.parts[part], self._buffer.arrays
        return StepResult({k: v[rows] for k, v in self._obs.items()}, flags["reward"][rows].copy(),
                          flags["terminated"][rows].copy(), flags["truncated"][rows].copy(), flags["acted"][rows].copy(),
                          flags["restarted"][rows].copy(), {k: v[rows] for k, v in self._first.items()})  # fmt: skip

    def _check_idle(self, what: str) -> None:
        if self._part_shards and any(a is not None for a in self._stepping):
            raise RuntimeError(f"BatchedDriving.{what}() while a part is stepping: end_step() it first")

    def _identity(self, slots: np.ndarray) -> bool:
        if self._arange is None or len(self._arange) != len(slots):
            self._arange = np.arange(len(slots))
        return bool((slots == self._arange).all())

    def close(self) -> None:
        for shards, began in zip(self._part_shards, self._stepping):
            if began is not None:  # a step left running (an interrupted collection)
                for shard in shards:
                    with contextlib.suppress(Exception):
                        shard.receive()
        self._stepping = [None] * len(self.parts)
        for shard in self.shards:
            shard.close()
        self.shards = []
        for group in self.groups:
            group.driving.close()
        if self._buffer is not None:
            self._obs = {k: v.copy() for k, v in self._obs.items()}  # readers may hold the last step
            self._first = {k: v.copy() for k, v in self._first.items()}
            self._buffer.release(unlink=True)
            self._buffer = None


def is_sumo(spec: ScenarioSpec) -> bool:
    return spec.traffic is not None and spec.traffic.engine == "sumo"


STEP_FLAGS = {
    "reward": np.float32,
    "terminated": np.bool_,
    "truncated": np.bool_,
    "acted": np.bool_,
    "restarted": np.bool_,
}
"""The per-slot results of a step besides the observations, as they lie in the shared buffer."""


def step_layout(space: gym.spaces.Dict, slots: int, action_width: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """Name -> (shape, dtype) of every array a step moves between this process and its workers:
    the observations and first observations (``obs/<key>``, ``first/<key>``), the flags of
    ``STEP_FLAGS`` and the actions, each over all ``slots``."""
    layout: dict[str, tuple[tuple[int, ...], str]] = {}
    for group in ("obs", "first"):
        for key, sub in space.spaces.items():
            layout[f"{group}/{key}"] = ((slots, *sub.shape), np.dtype(sub.dtype).str)
    for name, dtype in STEP_FLAGS.items():
        layout[name] = ((slots,), np.dtype(dtype).str)
    layout["actions"] = ((slots, action_width), np.dtype(np.float64).str)
    return layout


class SharedArrays:
    """Named arrays in one block of shared memory (``multiprocessing.shared_memory``): the buffer
    the workers write their slots' observations and flags into and this process reads in place,
    as a pool of environments does it (only a few bytes travel over the pipes). ``name`` attaches
    to a block another process made (the layout must be the same)."""

    ALIGN = 64  # every array starts on a cache line

    def __init__(self, layout: dict[str, tuple[tuple[int, ...], str]], name: str | None = None):
        from multiprocessing import shared_memory

        self.layout = layout
        offsets, size = {}, 0
        for key, (shape, dtype) in layout.items():
            offsets[key] = size
            nbytes = int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
            size += -(-max(nbytes, 1) // self.ALIGN) * self.ALIGN
        self.owner = name is None
        self.shm = (
            shared_memory.SharedMemory(create=True, size=max(size, 1))
            if self.owner
            else shared_memory.SharedMemory(name=name)
        )
        self.arrays = {key: np.ndarray(shape, dtype=np.dtype(dtype), buffer=self.shm.buf, offset=offsets[key])
                       for key, (shape, dtype) in layout.items()}  # fmt: skip
        if self.owner:
            for value in self.arrays.values():
                value[...] = 0

    @property
    def name(self) -> str:
        return self.shm.name

    def group(self, prefix: str) -> dict[str, np.ndarray]:
        """The arrays ``prefix/<key>`` by key (the observations, or the first observations)."""
        return {k.split("/", 1)[1]: v for k, v in self.arrays.items() if k.startswith(prefix + "/")}

    def release(self, unlink: bool = False) -> None:
        """Drop the views and unmap the block; the owner also frees it (``unlink``)."""
        self.arrays = {}
        try:
            self.shm.close()
        except BufferError:  # a view still held elsewhere: the mapping goes with the process
            pass
        if unlink:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


def _rows(slots: np.ndarray) -> slice | np.ndarray:
    """A worker's rows of the shared buffer: a slice when its slots are one block (copies are
    shared out in contiguous blocks), else the index array (a SUMO copy among others)."""
    if len(slots) and np.array_equal(slots, np.arange(slots[0], slots[0] + len(slots))):
        return slice(int(slots[0]), int(slots[0]) + len(slots))
    return slots


class _Shard:
    """Some copies of a ``BatchedDriving`` stepped as a ``BatchedDriving`` of their own in a worker
    process (``slots``: their slots in the parent's numbering). Commands and acknowledgements are
    small tuples over a pipe; actions, observations and flags go through the parent's shared
    buffer (``SharedArrays``), each worker reading and writing its own rows (``rows``). The worker
    answers every command, with ``("error", message, exception)`` on failure."""

    def __init__(self, parent: BatchedDriving, copies: list[int], options: dict, slots: list[int]):
        from smarts.worker_processes import worker_context

        ctx = worker_context()
        self.copies = copies
        self.slots = np.array(slots, dtype=np.int64)
        self.rows = _rows(self.slots)
        self.sources = [parent.specs[i].source for i in copies]
        self.conn, child = ctx.Pipe()
        specs = [parent.specs[i] for i in copies]
        ids = [parent.copy_ids[i] for i in copies]
        self.process = ctx.Process(target=_serve, args=(child, specs, ids, options), daemon=True)
        self.process.start()
        child.close()
        self.boxes: list = []
        self.spaces: list = []

    def started(self) -> None:
        """Wait for the worker's simulation: its slots' action and observation spaces."""
        self.boxes, self.spaces = self.receive()

    def attach(self, buffer: SharedArrays) -> None:
        """Give the worker the shared buffer and its rows in it."""
        self.call("attach", (buffer.name, buffer.layout, self.slots))

    def send(self, command: str, payload) -> None:
        self.conn.send((command, payload))

    def receive(self):
        try:
            reply = self.conn.recv()
        except EOFError:
            code = self.process.exitcode
            raise WorkerError(f"the worker process of {self.sources} ended (exit code {code})") from None
        if reply[0] == "error":
            _, message, exc = reply
            if isinstance(exc, (ActionError, ScenarioError, ValueError)):
                raise exc
            raise WorkerError(f"in the worker process of {self.sources}:\n{message}")
        return reply[1]

    def call(self, command: str, payload):
        self.send(command, payload)
        return self.receive()

    def check(self, actions: np.ndarray) -> None:
        """The check that needs no simulation (finite numbers): a worker refusing its share after
        others moved would break the step's atomicity."""
        mine = actions[self.slots]
        finite = np.isfinite(mine).all(axis=1)
        if not finite.all():
            bad = [f"slot {j}" for j in self.slots[~finite].tolist()]
            raise ActionError(f"actions of {bad} ({self.sources}) are not finite numbers", bad)

    def close(self) -> None:
        try:
            self.send("close", None)
            self.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            pass
        self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.kill()


class _Rows:
    """A worker's view of its rows in the parent's shared buffer."""

    def __init__(self, name: str, layout: dict, slots: np.ndarray):
        self.buffer = SharedArrays(layout, name)
        slots = np.asarray(slots, dtype=np.int64)
        self.rows, self.slots = _rows(slots), slots
        self.obs, self.first = self.buffer.group("obs"), self.buffer.group("first")

    def write_obs(self, obs: dict[str, np.ndarray]) -> None:
        for key, value in obs.items():
            self.obs[key][self.rows] = value

    def write_step(self, res: StepResult) -> None:
        self.write_obs(res.obs)
        arrays = self.buffer.arrays
        for name in STEP_FLAGS:
            arrays[name][self.rows] = getattr(res, name)
        again = np.flatnonzero(res.restarted)
        if len(again):
            for key, value in res.first.items():
                self.first[key][self.slots[again]] = value[again]

    def actions(self, width: int) -> np.ndarray:
        return self.buffer.arrays["actions"][self.rows, :width]


def _serve(conn, specs: list, copy_ids: list[int], options: dict) -> None:
    """A worker: one ``BatchedDriving`` of ``specs`` answering the parent's commands, its inputs and
    outputs in its rows of the parent's shared buffer."""
    import traceback

    try:
        env = BatchedDriving(specs, copy_ids=copy_ids, in_worker=True, **options)
        conn.send(("ok", (env.slot_action_spaces, [env.observation_space] * env.num_slots)))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent
        conn.send(("error", traceback.format_exc(), exc if isinstance(exc, Exception) else None))
        return
    rows: _Rows | None = None
    while True:
        command, payload = conn.recv()
        try:
            if command == "close":
                env.close()
                if rows is not None:
                    rows.obs = rows.first = {}
                    rows.buffer.release()
                conn.send(("ok", None))
                return
            if command == "attach":
                rows = _Rows(*payload)
                conn.send(("ok", None))
            elif command == "seed":
                env.set_seed(payload)
                conn.send(("ok", None))
            elif command == "reset":
                rows.write_obs(env.reset(payload))
                conn.send(("ok", None))
            elif command == "step":
                rows.write_step(env.step(rows.actions(env.action_width)))
                conn.send(("ok", None))
        except Exception as exc:  # noqa: BLE001 - reported to the parent
            conn.send(("error", traceback.format_exc(), exc))


def _space_difference(first: gym.spaces.Dict, other: gym.spaces.Dict) -> str:
    """The keys one observation space has and the other lacks, or the first key whose shape differs."""
    only_first, only_other = (
        sorted(set(first.spaces) - set(other.spaces)),
        sorted(set(other.spaces) - set(first.spaces)),
    )
    if only_first or only_other:
        parts = [
            f"{', '.join(keys)} only in {where}"
            for keys, where in ((only_first, "the first"), (only_other, "this one"))
            if keys
        ]
        return "; ".join(parts)
    for key in first.spaces:
        if first.spaces[key] != other.spaces[key]:
            return f"{key}: {first.spaces[key].shape} against {other.spaces[key].shape}"
    return "the spaces' bounds"
