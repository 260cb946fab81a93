"""Benchmark episodes stepped together in one simulation of the batched core.

The per-episode runner (``smarts.benchmark.runner.run_episode``) builds an env per episode and
steps it alone. Here the episodes of agents that drive alike (the same action space, controller
and observation interface: the reference agents, say; any scenarios of a suite, each with its
own seed) are the B episodes of one ``smarts.env.driving.Driving``: one simulation step, one
observation pass and, for each policy that allows it, one ``act`` call per step for all of its
episodes. Each episode is
recorded by its own ``EpisodeRecorder`` on ``sim.episode_sim(b)`` and follows the per-episode
loop's rules exactly (it acts while it has agents and time; a following task ends when a lead
leaves the map and otherwise runs on to its time limit after its agents are gone), so, as the core
steps an episode to the same bits whatever it runs beside, its log equals the per-episode one.

Only the normal flow runs here. An episode that meets anything else (its policy raises or returns
a malformed action, its observation space does not suit the policy, its recorder fails) leaves the
batch at once, untouched, and is returned to the caller to run alone, where the per-episode loop
records exactly what it always did. Episodes that cannot share a simulation at all
(``smarts.benchmark.batching.solo_reason``: SUMO traffic, social agents whose policies cannot be shared) are never
given here.

How a policy may be shared is its own declaration, ``policy.batching`` (:data:`BATCHING`); a
policy without one runs every episode alone, as before.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from smarts.benchmark.batching import BATCHING
from smarts.benchmark.metrics.log import EpisodeLog
from smarts.benchmark.recorder import EpisodeRecorder, EpisodeRecorders
from smarts.core.errors import ActionError
from smarts.core.following import lead_rows
from smarts.core.policies import Policy
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface


@dataclass
class BatchEpisode:
    """One episode of a batch: what the per-episode runner would build and record for it."""

    spec: ScenarioSpec
    """The suite scenario with the policy's action space and controller (``scenario_for``)."""
    seed: int
    recorder: dict[str, Any]
    """``EpisodeRecorder`` keywords: scenario, task, episode, seed, time_limit, follow, info."""
    policy: Policy
    """The policy that acts in it: its agent's one instance (shared by that agent's episodes of
    ``rows`` and ``episodes`` batching), or its own (``instances``)."""
    mode: str
    """The policy's batching (:data:`BATCHING`)."""
    leads: frozenset[str] = field(init=False)

    def __post_init__(self) -> None:
        self.leads = frozenset((self.recorder.get("follow") or {}).values())


ACT, COAST, DONE = 0, 1, 2
"""Phases of an episode in a batch: its agents act; its agents are gone and it runs on for the
lead (following tasks); over."""


class _Batch:
    """The loop over one simulation of B benchmark episodes (see the module's docstring)."""

    def __init__(self, episodes: Sequence[BatchEpisode], observation: AgentInterface | None,
                 lane_relative: LaneRelativeParams | None):  # fmt: skip
        from smarts.env.driving import Driving

        self.episodes = list(episodes)
        self.driving = Driving([e.spec for e in episodes], observation=observation, lane_relative=lane_relative)
        self.sim = self.driving.sim
        sim, learner = self.sim, self.driving.learner
        self.learners = [sim.views[b].agents[learner[sim.views[b].agents]] for b in range(len(episodes))]
        self.phase = np.full(len(episodes), ACT, dtype=np.int8)
        self.alone: list[int] = []
        self.last = {a: np.zeros(self.driving.action_space(a).shape, dtype=np.float32)
                     for a in np.flatnonzero(learner).tolist()}  # fmt: skip
        """Each learner's last action: what agents of episodes that left the batch keep sending."""
        self.recorders: list[EpisodeRecorder | None] = [None] * len(episodes)
        self.views = [sim.episode_sim(b) for b in range(len(episodes))]
        self.batches: list = []
        self.obs_group = np.full(len(sim.agent_ids), -1, dtype=np.int64)
        self.obs_row = np.full(len(sim.agent_ids), -1, dtype=np.int64)
        self.time_limit = np.array([e.recorder["time_limit"] for e in episodes], dtype=np.float64)
        self.learner_of = np.concatenate([np.full(len(a), b) for b, a in enumerate(self.learners)]).astype(np.int64)
        self.all_learners = np.concatenate(self.learners).astype(np.int64)
        follows = [(b, a) for b, e in enumerate(episodes) for a in self._lead_probes(b, e)]
        self.probe_episode = np.array([b for b, _ in follows], dtype=np.int64)
        self.probes = np.array([a for _, a in follows], dtype=np.int64)
        """One agent per lead of each episode (one that follows it), whose lead's row says whether
        that lead is still on the map."""
        self.has_leads = np.array([bool(e.leads) for e in episodes])

    def eject(self, b: int) -> None:
        """Episode ``b`` leaves the batch, to run alone."""
        if self.phase[b] != DONE:
            self.phase[b] = DONE
            self.alone.append(b)

    def start(self) -> None:
        """Reset every episode with its seed, start its recorder and check the policy's space."""
        sim = self.sim
        _, batches, _ = self.driving.reset(np.arange(len(self.episodes)), [e.seed for e in self.episodes])
        self.keep(_learner_batches(batches, self.driving.learner))
        ids = sim.local_agent_ids
        for b, episode in enumerate(self.episodes):
            agents = [ids[a] for a in self.learners[b].tolist()]
            try:
                self.recorders[b] = EpisodeRecorder(self.views[b], agents, **episode.recorder)
                if hasattr(episode.policy, "check_space"):
                    episode.policy.check_space(self.driving.observation_space(int(self.learners[b][0])))
            except Exception:  # noqa: BLE001 - alone, it is recorded as it always was
                self.eject(b)
        kept = [b for b in range(len(self.episodes)) if self.phase[b] != DONE]
        self.place = {b: i for i, b in enumerate(kept)}
        self.group = EpisodeRecorders(sim, [self.recorders[b] for b in kept], kept) if kept else None

    def run(self, finished: Callable[[int, EpisodeLog], None]) -> None:
        """Step until every episode is over, handing each finished log to ``finished(b, log)``."""
        while (self.phase != DONE).any():
            actions = self.actions()
            if not self.step(actions):
                return
            going = np.flatnonzero(self.phase != DONE)
            self.group.record([self.place[b] for b in going.tolist()])
            self.sim.remove_done_agents()
            self.phase[going] = self.next_phase()[going]
            for b in going[self.phase[going] == DONE].tolist():
                try:
                    log = self.recorders[b].finish()
                except Exception:  # noqa: BLE001 - alone, it ends as it always did
                    self.alone.append(b)
                    continue
                finished(b, log)

    def next_phase(self) -> np.ndarray:
        """The per-episode loop's rule for what each episode does after a step (for all at once)."""
        sim = self.sim
        in_time = sim.episode_time < self.time_limit - 1e-9
        lead_gone = np.zeros(len(self.episodes), dtype=bool)
        if len(self.probes):
            lead_gone[self.probe_episode[lead_rows(sim, self.probes) < 0]] = True
        live = np.zeros(len(self.episodes), dtype=bool)
        live[self.learner_of[sim.agent_active[self.all_learners]]] = True
        return np.select(
            [lead_gone, (self.phase == ACT) & live & in_time, ~live & self.has_leads & in_time],
            [DONE, ACT, COAST],  # the lead left the map: the following task is over; its agents act;
            DONE,  # its agents are gone and it runs on to where the lead gets to; otherwise over
        ).astype(np.int8)

    def _lead_probes(self, b: int, episode: BatchEpisode) -> list[int]:
        """For each lead of episode ``b``, an agent of it that follows that lead."""
        view = self.views[b]
        probes = {}
        for a in self.sim.views[b].agents.tolist():
            lead = view.lead_ids[a]
            if lead in episode.leads:
                probes.setdefault(lead, a)
        missing = episode.leads - set(probes)
        if missing:  # (the recorder checks the suite's follow against the missions: never here)
            raise ValueError(f"episode {b}: no agent follows {sorted(missing)}")
        return list(probes.values())

    def acting(self) -> list[int]:
        return np.flatnonzero(self.phase == ACT).tolist()

    def actions(self) -> dict[str, np.ndarray]:
        """Every active learner's action by agent id: the policies' for the acting episodes, the
        last one for the agents of episodes that are over."""
        sim = self.sim
        chosen: dict[int, np.ndarray] = {}
        stacked = []
        for b in self.acting():
            e = self.episodes[b]
            if e.mode == "rows" or (e.mode == "episodes" and hasattr(e.policy, "act_episodes")):
                stacked.append(b)
            else:
                self._act_one(b, chosen)
        self._act_stacked(stacked, chosen)
        ids = sim.agent_ids
        out = {}
        for a in sim.active_agents[self.driving.learner[sim.active_agents]].tolist():
            if a in chosen:
                self.last[a] = chosen[a]
            out[ids[a]] = self.last[a]
        return out

    def _rows(self, agents: np.ndarray) -> dict[str, np.ndarray]:
        """The observations of ``agents`` (ascending, one observation group), stacked as the
        per-episode loop stacks them."""
        group, at = self.obs_group[agents[0]], self.obs_row[agents]
        if (self.obs_group[agents] != group).any() or (at < 0).any():
            raise ValueError("agents without an observation, or of different observation groups")
        return {k: v[at] for k, v in self.batches[group][1].items()}

    def keep(self, batches: list) -> None:
        """The learners' observations after a step (or the reset), and where each agent's is."""
        self.batches = list(batches)
        self.obs_group[:] = -1
        self.obs_row[:] = -1
        for g, (members, _) in enumerate(self.batches):
            self.obs_group[members] = g
            self.obs_row[members] = np.arange(len(members))

    def _live(self, b: int) -> np.ndarray:
        agents = self.learners[b]
        return agents[self.sim.agent_active[agents]]

    def _act_one(self, b: int, chosen: dict[int, np.ndarray]) -> None:
        """One call of episode ``b``'s policy for its live agents; anything odd sends it alone."""
        agents = self._live(b)
        try:
            actions = np.asarray(self.episodes[b].policy.act(self._rows(agents)))
            if actions.ndim != 2 or len(actions) != len(agents):
                raise ValueError("malformed actions")
        except Exception:  # noqa: BLE001 - alone, it fails the way it always did
            self.eject(b)
            return
        chosen.update(zip(agents.tolist(), actions))

    def _act_stacked(self, acting: list[int], chosen: dict[int, np.ndarray]) -> None:
        """One call per policy and observation group for the live agents of the ``acting``
        episodes (``act`` of ``rows`` batching, or ``act_episodes`` of a policy of ``episodes``
        batching that has it); a call that fails is made again episode by episode, so only the
        episodes at fault leave."""
        if not acting:
            return
        live = {b: self._live(b) for b in acting}
        by_group: dict[tuple[int, int], list[int]] = {}
        for b in acting:
            by_group.setdefault((id(self.episodes[b].policy), int(self.obs_group[live[b][0]])), []).append(b)
        for members in by_group.values():
            agents = np.concatenate([live[b] for b in members])
            policy, mode = self.episodes[members[0]].policy, self.episodes[members[0]].mode
            try:
                if mode == "rows":
                    actions = np.asarray(policy.act(self._rows(agents)))
                else:  # one call, each episode's rows apart where it matters (act_episodes)
                    actions = np.asarray(policy.act_episodes(self._rows(agents), [len(live[b]) for b in members]))
                if actions.ndim != 2 or len(actions) != len(agents):
                    raise ValueError("malformed actions")
            except Exception:  # noqa: BLE001
                for b in members:
                    self._act_one(b, chosen)
                continue
            chosen.update(zip(agents.tolist(), actions))

    def step(self, actions: dict[str, np.ndarray]) -> bool:
        """One step of the simulation; an action the simulation refuses (nothing moved) sends its
        episode alone and the step is made again without it. False when the batch cannot go on
        (every episode still in it then runs alone)."""
        while (self.phase == ACT).any() or (self.phase == COAST).any():
            try:
                self.keep(self.driving.step(actions).batches)
                return True
            except ActionError as err:
                bad = self._episodes_of(err.agent_ids) or set(self.acting())
                if not bad:
                    break
                for b in bad:
                    self.eject(b)
                    for a in self._live(b).tolist():
                        actions[self.sim.agent_ids[a]] = self.last[a]
            except Exception:  # noqa: BLE001 - the simulation itself failed
                break
        for b in np.flatnonzero(self.phase != DONE).tolist():
            self.eject(b)
        return False

    def _episodes_of(self, agent_ids: Sequence[str]) -> set[int]:
        """The acting episodes of agents named in an ``ActionError`` (empty when one is unknown)."""
        index = self.sim.agent_index
        out = set()
        for name in agent_ids:
            a = index.get(name)
            if a is None or self.phase[int(self.sim.agent_episode[a])] != ACT:
                return set()
            out.add(int(self.sim.agent_episode[a]))
        return out


def _learner_batches(batches: list, learner: np.ndarray) -> list:
    from smarts.env.driving import learner_batches

    return learner_batches(batches, learner)


def run_batch(
    episodes: Sequence[BatchEpisode],
    observation: AgentInterface | None,
    lane_relative: LaneRelativeParams | None,
    finished: Callable[[int, EpisodeLog], None],
) -> list[int]:
    """Step ``episodes`` (each ``solo_reason``-free, their policies all driving with
    ``observation`` and ``lane_relative``) as one simulation, calling ``finished(i, log)`` as
    episode ``i`` ends; returns the episodes to run alone instead (they left the batch untouched,
    or the batch could not be built)."""
    for e in episodes:
        if e.mode not in BATCHING:
            raise ValueError(f"batching {e.mode!r}: expected one of {', '.join(BATCHING)}")
    try:
        batch = _Batch(episodes, observation, lane_relative)
    except Exception:  # noqa: BLE001 - alone, each episode reports what is wrong with it
        return list(range(len(episodes)))
    try:
        batch.start()
        batch.run(finished)
    except Exception:  # noqa: BLE001
        for b in np.flatnonzero(batch.phase != DONE).tolist():
            batch.eject(b)
    finally:
        batch.driving.close()
    return sorted(batch.alone)
