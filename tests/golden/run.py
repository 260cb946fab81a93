"""Stepping a golden case on a backend and hashing what it gives, step by step.

Four streams are hashed per step of an episode:
- ``table``: every live row of the episode's vehicle table in row order: its row within the
  episode, id, x, y, heading and speed (float64 bits);
- ``obs``: the observation of every learning agent that acted, in scenario order, every key;
- ``reward``: their rewards (as float32);
- ``events``: their event flags and terminated/truncated flags.

A step's record is 8 hex digits, 2 of each stream's digest of that step alone (so a mismatch names
the first step and stream that differ, short enough to commit thousands of steps); an episode also
keeps the chained digest of each stream over all its steps, which no difference escapes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from tests.golden.cases import MAX_STEPS, golden_actions

STREAMS = ("table", "obs", "reward", "events")


def _digest(parts: list[bytes]) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    for p in parts:
        h.update(len(p).to_bytes(8, "little"))
        h.update(p)
    return h.digest()


@dataclass
class EpisodeRecord:
    steps: list[str] = field(default_factory=list)
    chains: dict[str, bytes] = field(default_factory=lambda: {s: b"" for s in STREAMS})

    def add(self, table: bytes, obs: bytes, reward: bytes, events: bytes) -> None:
        short = []
        for name, value in zip(STREAMS, (table, obs, reward, events)):
            d = _digest([value])
            self.chains[name] = _digest([self.chains[name], d])
            short.append(d.hex()[:2])
        self.steps.append("".join(short))

    def to_json(self) -> dict:
        return {"steps": "".join(self.steps), **{k: v.hex() for k, v in self.chains.items()}}

    def first_difference(self, golden: dict, streams: tuple[str, ...] = STREAMS) -> str | None:
        """None when this episode is the golden one in ``streams``; else where it first differs."""
        mine = self.to_json()
        keep = [STREAMS.index(s) for s in streams]
        width = 2 * len(STREAMS)
        theirs = golden["steps"]

        def part(code: str) -> str:
            return "".join(code[2 * i : 2 * i + 2] for i in keep)

        if mine["steps"] != theirs and len(mine["steps"]) != len(theirs):
            pass
        for k in range(max(len(self.steps), len(theirs) // width)):
            a, b = mine["steps"][k * width : (k + 1) * width], theirs[k * width : (k + 1) * width]
            if not a or not b:
                return f"length {len(self.steps)} steps, golden {len(theirs) // width}"
            if part(a) != part(b):
                differ = [STREAMS[i] for i in keep if a[2 * i : 2 * i + 2] != b[2 * i : 2 * i + 2]]
                return f"step {k}: {', '.join(differ)}"
        differ = [s for s in streams if mine[s] != golden[s]]
        return f"chained digests of {', '.join(differ)}" if differ else None


def table_bytes(ids: list, alive: np.ndarray, x, y, heading, speed) -> bytes:
    """The ``table`` stream of one episode: ``alive`` its live rows (episode-local, ascending)."""
    rows = np.flatnonzero(alive)
    parts = [rows.astype(np.int64).tobytes(), "\0".join(str(ids[r]) for r in rows.tolist()).encode()]
    for col in (x, y, heading, speed):
        parts.append(np.ascontiguousarray(col[rows], dtype=np.float64).tobytes())
    return _digest(parts)


def obs_bytes(per_agent: list[dict[str, np.ndarray]]) -> bytes:
    parts = []
    for obs in per_agent:
        for key in sorted(obs):
            v = np.ascontiguousarray(obs[key])
            parts += [key.encode(), str(v.dtype).encode(), repr(v.shape).encode(), v.tobytes()]
    return _digest(parts)


def reward_bytes(rewards) -> bytes:
    return np.asarray(rewards, dtype=np.float32).tobytes()


def events_bytes(events: np.ndarray, terminated, truncated) -> bytes:
    return _digest([
        np.ascontiguousarray(events, dtype=bool).tobytes(),
        np.asarray(terminated, dtype=bool).tobytes(),
        np.asarray(truncated, dtype=bool).tobytes(),
    ])  # fmt: skip


def _kinds(spec, agent_ids: list[str]) -> list[tuple[str, str]]:
    by_id = {a.id: a for a in spec.agents}
    return [(by_id[a].action_space, by_id[a].controller) for a in agent_ids]


# ---------------------------------------------------------------------------- per-env backend
def run_single(spec, seed: int, max_steps: int = MAX_STEPS) -> EpisodeRecord:
    """One episode of ``spec`` with ``seed`` on ``DrivingParallelEnv``."""
    from smarts.env import DrivingParallelEnv

    env = DrivingParallelEnv(spec)
    try:
        return _run_single(env, spec, seed, max_steps)
    finally:
        env.close()


def _run_single(env, spec, seed: int, max_steps: int) -> EpisodeRecord:
    sim = env.sim
    learners = set(env.possible_agents)
    local = {a.id: i for i, a in enumerate(spec.agents)}
    message = len(env.comms.message_components) if env.comms is not None else 0
    seen: dict = {}

    def listener(s) -> None:
        acting = [a for a in s.active_agents.tolist() if s.agent_ids[a] in learners]
        t = s.table
        seen["table"] = table_bytes(t.ids, t.alive, t.x, t.y, t.heading, t.speed)
        seen["events"] = s.agent_events[acting].copy()

    env.add_step_listener(listener)
    record = EpisodeRecord()
    obs, _ = env.reset(seed=seed)
    t = sim.table
    first = [a for a in sim.active_agents.tolist() if sim.agent_ids[a] in learners]
    record.add(
        table_bytes(t.ids, t.alive, t.x, t.y, t.heading, t.speed),
        obs_bytes([obs[a] for a in env.agents]),
        b"",
        events_bytes(sim.agent_events[first], [], []),
    )
    for step in range(1, max_steps + 1):
        if not env.agents:
            break
        ids = list(env.agents)
        batch = {k: np.stack([obs[a][k] for a in ids]) for k in obs[ids[0]]}
        rows = sim.agent_row[[sim.agent_index[a] for a in ids]]
        poses = np.stack([t.x[rows], t.y[rows], t.heading[rows]], axis=1)
        kinds = _kinds(spec, ids)
        acts = golden_actions(
            batch, kinds, poses, np.array([local[a] for a in ids]), step - 1, spec.step_length, message
        )
        actions = {a: acts[i, : _width(kinds[i]) + message] for i, a in enumerate(ids)}
        obs, rewards, terms, truncs, _ = env.step(actions)
        acted = list(rewards)
        record.add(
            seen["table"],
            obs_bytes([obs[a] for a in acted]),
            reward_bytes([rewards[a] for a in acted]),
            events_bytes(seen["events"], [terms[a] for a in acted], [truncs[a] for a in acted]),
        )
    return record


def _width(kind: tuple[str, str]) -> int:
    space, controller = kind
    return 2 if controller == "lane_relative" or space == "lane" else 3


# ---------------------------------------------------------------------------- batched backend
def run_batched(specs: list, seeds: list[int], max_steps: int = MAX_STEPS) -> list[EpisodeRecord]:
    """The first episode of each copy (``specs[i]`` with ``seeds[i]``) on the batched backend,
    all copies in one ``BatchedDriving``."""
    from smarts.env.batched import BatchedDriving

    bd = BatchedDriving(specs)
    try:
        return _run_batched(bd, specs, seeds, max_steps)
    finally:
        bd.close()


def _episode_table(bd, copy: int):
    """The copy's simulation, its episode's table and index; None for a copy in a worker process
    (SUMO), whose table this process cannot see."""
    if bd.copy_place[copy] is None:
        return None
    g, b = bd.copy_place[copy]
    sim = bd.groups[g].sim
    return sim, sim.views[b].table, b


def _run_batched(bd, specs: list, seeds: list[int], max_steps: int) -> list[EpisodeRecord]:
    n_copies = len(specs)
    slots = bd.slots
    slot_copy = np.array([c for c, _ in slots])
    local = np.array([[a.id for a in specs[c].agents].index(aid) for c, aid in slots])
    kinds = [_kinds(specs[c], [aid])[0] for c, aid in slots]
    links = [link for g in bd.groups for link in g.driving.links if link is not None]
    message = len(links[0].message_components) if links else 0
    seen: dict = {}

    slot_agent: list[tuple | None] = [None] * len(slots)  # slot -> (group simulation, agent); None: remote
    for g in bd.groups:
        for a, j in enumerate(g.agent_slot.tolist()):
            if j >= 0:
                slot_agent[j] = (g.sim, a)

    def tables() -> list[bytes]:
        out = []
        for c in range(n_copies):
            found = _episode_table(bd, c)
            out.append(b"" if found is None else table_bytes(found[1].ids, found[1].alive, found[1].x, found[1].y,
                                                             found[1].heading, found[1].speed))  # fmt: skip
        return out

    def events_of(sel: np.ndarray) -> np.ndarray:
        rows = [
            slot_agent[j][0].agent_events[slot_agent[j][1]] if slot_agent[j] else obs["events"][j] > 0
            for j in sel.tolist()
        ]
        return np.array(rows, dtype=bool).reshape(len(sel), -1)

    def listener() -> None:
        seen["tables"] = tables()
        seen["events"] = {
            j: s.agent_events[a].copy() for j, sa in enumerate(slot_agent) if sa for s, a in [sa] if s.agent_active[a]
        }

    bd.add_step_listener(listener)
    obs = bd.reset(seeds)
    records = [EpisodeRecord() for _ in range(n_copies)]
    for c, tb in enumerate(tables()):
        sel = np.flatnonzero(slot_copy == c)
        records[c].add(tb, obs_bytes([{k: v[j] for k, v in obs.items()} for j in sel]), b"",
                       events_bytes(events_of(sel), [], []))  # fmt: skip
    done_copies = np.zeros(n_copies, dtype=bool)
    for step in range(1, max_steps + 1):
        if done_copies.all():
            break
        poses = np.zeros((len(slots), 3))  # (remote copies: no world-frame actions in SUMO cases)
        for j, sa in enumerate(slot_agent):
            if sa is None:
                continue
            sim, a = sa
            r = sim.agent_row[a]
            if r >= 0:
                poses[j] = (sim.table.x[r], sim.table.y[r], sim.table.heading[r])
        acts = golden_actions(obs, kinds, poses, local, step - 1, specs[0].step_length, message)
        acts = acts[:, : bd.action_width]
        result = bd.step(acts)
        obs = result.obs
        for c in np.flatnonzero(~done_copies).tolist():
            sel = np.flatnonzero((slot_copy == c) & result.acted)
            records[c].add(
                seen["tables"][c],
                obs_bytes([{k: v[j] for k, v in obs.items()} for j in sel]),
                reward_bytes(result.reward[sel]),
                events_bytes(
                    np.array(
                        [seen["events"][j] if j in seen["events"] else obs["events"][j] > 0 for j in sel.tolist()],
                        dtype=bool,
                    ).reshape(len(sel), -1),
                    result.terminated[sel],
                    result.truncated[sel],
                ),
            )
            if result.restarted[slot_copy == c].any():
                done_copies[c] = True
    return records


# ---------------------------------------------------------------------------- one simulation
def run_engine(specs: list, seeds: list[int], max_steps: int = MAX_STEPS) -> list[EpisodeRecord]:
    """The first episode of each of ``specs`` (with ``seeds``) as one simulation of the env engine
    (``smarts.env.driving.Driving``): every case together, whatever its maps, sensors, action
    spaces, social agents and V2V."""
    from smarts.env.driving import Driving

    engine = Driving(specs, seeds=seeds)
    try:
        return _run_engine(engine, specs, max_steps)
    finally:
        engine.close()


def _run_engine(engine, specs: list, max_steps: int) -> list[EpisodeRecord]:
    sim = engine.sim
    n = len(specs)
    learner = engine.learner
    kinds = [_kinds(specs[b], [aid])[0] for b, aid in zip(sim.agent_episode.tolist(), sim.local_agent_ids)]
    local = np.array(
        [[a.id for a in specs[b].agents].index(aid) for b, aid in zip(sim.agent_episode.tolist(), sim.local_agent_ids)]
    )
    message = np.array([len(link.message_components) if link is not None else 0 for link in engine.links])
    width = int(max(engine.action_space(a).shape[0] for a in range(len(sim.agent_ids))))
    seen: dict = {}

    def tables() -> list[bytes]:
        return [
            table_bytes(v.table.ids, v.table.alive, v.table.x, v.table.y, v.table.heading, v.table.speed)
            for v in sim.views
        ]

    def listener(s) -> None:
        seen["tables"] = tables()
        seen["events"] = s.agent_events.copy()
        seen["active"] = s.agent_active.copy()

    engine.add_step_listener(listener)
    agents, batches, _ = engine.reset(np.arange(n))
    obs = _per_agent(batches)
    records = [EpisodeRecord() for _ in range(n)]
    for b, tb in enumerate(tables()):
        mine = [a for a in agents.tolist() if sim.agent_episode[a] == b and learner[a]]
        records[b].add(tb, obs_bytes([obs[a] for a in mine]), b"", events_bytes(sim.agent_events[mine], [], []))
    over = np.zeros(n, dtype=bool)
    for step in range(1, max_steps + 1):
        active = sim.active_agents
        acting = active[learner[active]]
        if acting.size == 0:
            break
        actions = np.zeros((len(sim.agent_ids), width), dtype=np.float32)
        for b in np.unique(sim.agent_episode[acting]).tolist():
            mine = acting[sim.agent_episode[acting] == b]
            batch = {k: np.stack([obs[a][k] for a in mine.tolist()]) for k in obs[int(mine[0])]}
            rows = sim.agent_row[mine]
            poses = np.stack([sim.table.x[rows], sim.table.y[rows], sim.table.heading[rows]], axis=1)
            acts = golden_actions(batch, [kinds[a] for a in mine.tolist()], poses, local[mine], step - 1,
                                  specs[b].step_length, int(message[b]))  # fmt: skip
            actions[mine, : acts.shape[1]] = acts[:, :width]
        res = engine.step(actions)
        obs.update(_per_agent(res.batches))
        for b in np.flatnonzero(~over).tolist():
            sel = np.flatnonzero(sim.agent_episode[res.agents] == b)
            mine = res.agents[sel]
            records[b].add(
                seen["tables"][b],
                obs_bytes([obs[a] for a in mine.tolist()]),
                reward_bytes(res.reward[sel]),
                events_bytes(seen["events"][mine], res.terminated[sel], res.truncated[sel]),
            )
        sim.remove_done_agents()
        ended = sim.episodes_over()
        over[ended] = True
    return records


def _per_agent(batches) -> dict[int, dict[str, np.ndarray]]:
    out = {}
    for members, batch in batches:
        for i, a in enumerate(members.tolist()):
            out[a] = {k: np.array(v[i]) for k, v in batch.items()}
    return out
