"""Stable-Baselines3 adapter: every agent of every env copy is one VecEnv slot.

SB3 trains one policy over a batch of independent slots, so a multi-agent env maps onto it by
parameter sharing: ``num_envs`` = the sum over env copies of ``len(possible_agents)``, with copy
``k``'s agents in consecutive slots. Env copies run in this process, or one per worker process
(``processes=True``), which SUMO scenarios need because libsumo holds one simulation per process.

Slot semantics (what SB3's PPO needs: every slot yields an observation every step):

- Actions come for every slot; those of slots whose agent is not live are ignored.
- When an agent finishes, its slot reports ``done=True`` exactly once, with
  ``info["terminal_observation"]`` (its final observation), ``info["TimeLimit.truncated"]`` (True
  when only the step limit ended it, so PPO bootstraps from the terminal observation) and
  ``info["episode"] = {"r", "l", "t"}`` (return, length, seconds), the record SB3 logs.
- While the other agents of its copy drive on, a finished agent's slot is *inactive*: zero
  observation, reward 0, ``done=False`` and ``info["inactive"] = True``. PPO cuts GAE at the
  done, so these filler transitions never leak into the agent's real episode; they only add
  action-independent samples (their policy gradient is zero in expectation).
- When no agent of a copy is live, the copy resets within the same step (the SB3 convention):
  the slots get the new episode's first observations; ``reset_infos`` holds its reset infos.

Do not wrap this in ``VecMonitor``: it would count the inactive filler steps into episode lengths.
The ``episode`` records above already feed SB3's ``ep_rew_mean``/``ep_len_mean``. Recurrent
policies would carry state from the filler into the next episode, since its first step is not
flagged as an episode start.

Seeding: ``seed(s)`` (and the constructor's ``seed``) seeds copy ``k``'s next reset with
``s + first slot of k``; each later episode of a copy takes the next number of a stream seeded
by that value, so copies and episodes differ but a run is reproducible. A seed is an integer
from 0 to 2**64 - 1; anything else is a ``ValueError`` naming it.
"""

from __future__ import annotations

import multiprocessing as mp
import time
import traceback
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import cloudpickle
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from smarts.core.errors import ActionError, WorkerError
from smarts.core.simulation import check_seed, derived_seed
from smarts.dynamics.action_spaces import REAL_KINDS
from smarts.env.assembly import as_spec
from smarts.env.parallel_env import DrivingParallelEnv
from smarts.scenario import ScenarioSpec

EnvFactory = Callable[[], Any]
"""Builds one PettingZoo ParallelEnv (a ``DrivingParallelEnv`` or one with the same API)."""

_SEED_LIMIT = 2**31 - 1


class _EnvCopy:
    """One ParallelEnv seen as fixed slots: writes its agents' observations into slot rows, keeps
    track of who is live and restarts the episode when nobody is."""

    def __init__(self, env: Any, name: str):
        self.env = env
        self.name = name
        self.agents: list[str] = list(env.possible_agents)
        if not self.agents:
            raise ValueError(f"{name}: the env has no possible_agents")
        self.slot_of = {a: i for i, a in enumerate(self.agents)}
        space = env.observation_space(self.agents[0])
        self.is_dict = isinstance(space, spaces.Dict)
        self.keys = list(space.spaces) if self.is_dict else [None]
        self.returns = [0.0] * len(self.agents)
        self.lengths = [0] * len(self.agents)
        self.started = time.perf_counter()
        self._seeds: np.random.Generator | None = None

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None, options: dict | None, out: dict, offset: int) -> list[dict]:
        """Start an episode; ``seed`` restarts this copy's seed stream, None takes its next seed."""
        if seed is not None:
            self._seeds = np.random.default_rng(seed)
            episode_seed = int(seed)
        elif self._seeds is not None:
            episode_seed = int(self._seeds.integers(_SEED_LIMIT))
        else:
            episode_seed = None
        obs, infos = self.env.reset(seed=episode_seed, options=options or None)
        self.returns = [0.0] * len(self.agents)
        self.lengths = [0] * len(self.agents)
        self._write(obs, set(self.env.agents), out, offset)
        return [dict(infos.get(a, {})) for a in self.agents]

    def check(self, actions: np.ndarray) -> None:
        """Raise the ``ActionError`` that stepping ``actions`` would raise (naming this copy and
        the agents), changing nothing."""
        check = getattr(self.env, "check_actions", None)
        if check is None or not self.env.agents:
            return
        try:
            check({a: actions[self.slot_of[a]] for a in self.env.agents})
        except ActionError as err:
            raise ActionError(f"{self.name}: {err}", err.agent_ids) from None

    def step(
        self, actions: np.ndarray, out: dict, rewards: np.ndarray, dones: np.ndarray, offset: int
    ) -> tuple[list[dict], list[dict] | None]:
        """Step the live agents with their slots' actions; fill this copy's rows of ``out``,
        ``rewards`` and ``dones``. Returns the slots' infos, and the reset infos when the episode
        ended and the copy restarted (None otherwise)."""
        env = self.env
        slot_of = self.slot_of
        if not env.agents:
            raise RuntimeError(f"{self.name}: step() before reset(); call the VecEnv's reset() first")
        try:
            chosen = {a: actions[slot_of[a]] for a in env.agents}
        except KeyError as exc:
            raise ValueError(f"{self.name}: live agent {exc.args[0]!r} is not one of possible_agents") from None
        obs, rew, term, trunc, infos = env.step(chosen)
        live = set(env.agents)
        slot_infos: list[dict] = []
        for i, a in enumerate(self.agents):
            if a not in rew:
                slot_infos.append({"inactive": True})
                continue
            r = float(rew[a])
            rewards[offset + i] = r
            info = dict(infos.get(a, {}))
            self.returns[i] += r
            self.lengths[i] += 1
            if a not in live:
                dones[offset + i] = True
                info["TimeLimit.truncated"] = bool(trunc.get(a, False) and not term.get(a, False))
                info["terminal_observation"] = self._row(obs.get(a))
                info["episode"] = {
                    "r": self.returns[i],
                    "l": self.lengths[i],
                    "t": round(time.perf_counter() - self.started, 6),
                }
            slot_infos.append(info)
        if live:
            self._write(obs, live, out, offset)
            return slot_infos, None
        return slot_infos, self.reset(None, None, out, offset)

    # ------------------------------------------------------------------ rows
    def _write(self, obs: dict, live: set, out: dict, offset: int) -> None:
        """Copy live agents' observations into their rows (``out`` is zeroed: others stay zero)."""
        for i, a in enumerate(self.agents):
            if a in live and a in obs:
                o = obs[a]
                if self.is_dict:
                    for k in self.keys:
                        out[k][offset + i] = o[k]
                else:
                    out[None][offset + i] = o

    def _row(self, o: Any) -> Any:
        """A copy of one agent's observation, as SB3 expects a ``terminal_observation``."""
        if o is None:
            return None
        if self.is_dict:
            return {k: np.array(o[k]) for k in self.keys}
        return np.array(o)


def _zeros(keys: list, space: spaces.Space, n: int) -> dict:
    subspaces = space.spaces if isinstance(space, spaces.Dict) else {None: space}
    return {k: np.zeros((n, *subspaces[k].shape), dtype=subspaces[k].dtype) for k in keys}


def _spaces_of(env: Any) -> tuple[list[str], list[spaces.Space], list[spaces.Space]]:
    agents = list(env.possible_agents)
    return agents, [env.observation_space(a) for a in agents], [env.action_space(a) for a in agents]


def _is_wrapped(env: Any, wrapper_class: type) -> bool:
    while env is not None:
        if isinstance(env, wrapper_class):
            return True
        env = getattr(env, "env", None)
    return False


def _worker(remote: Any, parent_remote: Any, factory_bytes: bytes, name: str) -> None:
    """Run one env copy in this process, serving the parent's commands over a pipe."""
    parent_remote.close()
    copy: _EnvCopy | None = None
    while True:
        try:
            command, data = remote.recv()
        except (EOFError, KeyboardInterrupt):
            break
        try:
            if command == "build":
                copy = _EnvCopy(cloudpickle.loads(factory_bytes)(), name)
                reply: Any = _spaces_of(copy.env)
            elif command == "step":
                n = len(copy.agents)
                out = _zeros(copy.keys, copy.env.observation_space(copy.agents[0]), n)
                rewards, dones = np.zeros(n, np.float32), np.zeros(n, bool)
                infos, reset_infos = copy.step(data, out, rewards, dones, 0)
                reply = (out, rewards, dones, infos, reset_infos)
            elif command == "check":
                reply = copy.check(data)
            elif command == "reset":
                out = _zeros(copy.keys, copy.env.observation_space(copy.agents[0]), len(copy.agents))
                reply = (out, copy.reset(data[0], data[1], out, 0))
            elif command == "get_attr":
                reply = getattr(copy.env, data)
            elif command == "set_attr":
                reply = setattr(copy.env, data[0], data[1])
            elif command == "env_method":
                reply = getattr(copy.env, data[0])(*data[1], **data[2])
            elif command == "is_wrapped":
                reply = _is_wrapped(copy.env, data)
            elif command == "close":
                if copy is not None:
                    copy.env.close()
                remote.send(("ok", None))
                break
            else:
                raise ValueError(f"unknown command {command!r}")
            remote.send(("ok", reply))
        except Exception as exc:  # noqa: BLE001  (any failure goes back to the parent, which raises it)
            remote.send(("error", (type(exc).__name__, str(exc), traceback.format_exc())))
    remote.close()


class SmartsVecEnv(VecEnv):
    """SB3 VecEnv over copies of a multi-agent ParallelEnv, one slot per (copy, agent).

    ``env_fns`` build the copies (in worker processes they are sent with cloudpickle, so lambdas
    work). All agents of all copies must share one observation space and one action space (one
    shared policy). ``normalize_actions`` exposes ``Box(-1, 1)`` actions and maps them affinely
    onto the agents' action box, the scale SB3's Gaussian policies start from.
    ``start_method`` is the multiprocessing start method for ``processes=True`` (default
    ``forkserver`` where available, else ``spawn``; scripts then need an ``if __name__ ==
    "__main__":`` guard).
    """

    def __init__(
        self,
        env_fns: Sequence[EnvFactory],
        *,
        processes: bool = False,
        seed: int | None = 0,
        normalize_actions: bool = False,
        start_method: str | None = None,
    ):
        if not env_fns:
            raise ValueError("env_fns: need at least one env factory")
        self.processes = processes
        self._copies: list[_EnvCopy] = []
        self._remotes: list[Any] = []
        self._workers: list[Any] = []
        self._closed = False
        self._waiting = False
        self._actions: np.ndarray | None = None
        if processes:
            layouts = self._start_workers(env_fns, start_method)
        else:
            self._copies = [_EnvCopy(fn(), f"env copy {k}") for k, fn in enumerate(env_fns)]
            layouts = [_spaces_of(c.env) for c in self._copies]
        try:
            obs_space, act_space = self._shared_spaces(layouts)
        except (TypeError, ValueError):
            self.close()
            raise
        counts = [len(agents) for agents, _, _ in layouts]
        self.offsets: list[int] = np.concatenate([[0], np.cumsum(counts)]).tolist()
        self.slot_agents: list[tuple[int, str]] = [(k, a) for k, (agents, _, _) in enumerate(layouts) for a in agents]
        """``(copy index, agent id)`` of every slot."""
        self._copy_of_slot = np.repeat(np.arange(len(counts)), counts)
        self._keys = list(obs_space.spaces) if isinstance(obs_space, spaces.Dict) else [None]
        self._agent_action_space = act_space
        self.normalize_actions = normalize_actions
        if normalize_actions:
            if not isinstance(act_space, spaces.Box) or not np.all(
                np.isfinite(act_space.low) & np.isfinite(act_space.high)
            ):
                raise ValueError(f"normalize_actions needs a bounded Box action space, got {act_space}")
            self._act_low = act_space.low.astype(np.float64)
            self._act_half_range = (act_space.high.astype(np.float64) - self._act_low) / 2.0
            act_space = spaces.Box(-1.0, 1.0, act_space.shape, dtype=act_space.dtype)
        super().__init__(int(self.offsets[-1]), obs_space, act_space)
        if seed is not None:
            self.seed(check_seed(seed, "SmartsVecEnv(seed=...)"))

    @classmethod
    def from_scenario(
        cls,
        scenario: str | Path | ScenarioSpec,
        n_envs: int = 1,
        *,
        processes: bool = False,
        seed: int | None = 0,
        normalize_actions: bool = False,
        start_method: str | None = None,
        **env_kwargs: Any,
    ) -> SmartsVecEnv:
        """``n_envs`` copies of ``DrivingParallelEnv(scenario, **env_kwargs)``. A SUMO scenario
        with more than one copy needs ``processes=True`` (libsumo: one simulation per process)."""
        if n_envs < 1:
            raise ValueError(f"n_envs must be at least 1, got {n_envs}")
        spec = as_spec(scenario)
        traffic = spec.traffic
        if traffic is not None and traffic.engine == "sumo" and n_envs > 1 and not processes:
            raise ValueError(
                f"{spec.source}: uses SUMO traffic, and libsumo runs one simulation per process; "
                f"{n_envs} copies need processes=True"
            )
        factory = partial(DrivingParallelEnv, spec, **env_kwargs)
        return cls(
            [factory] * n_envs,
            processes=processes,
            seed=seed,
            normalize_actions=normalize_actions,
            start_method=start_method,
        )

    # ------------------------------------------------------------------ setup
    def _start_workers(self, env_fns: Sequence[EnvFactory], start_method: str | None) -> list:
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        context = mp.get_context(start_method)
        if start_method == "forkserver":
            # The server imports this module (and so SB3 and torch) once; workers fork from it
            # instead of each paying that import. No effect once the server already runs.
            context.set_forkserver_preload([__name__])
        for k, fn in enumerate(env_fns):
            remote, child = context.Pipe()
            process = context.Process(
                target=_worker, args=(child, remote, cloudpickle.dumps(fn), f"env copy {k}"), daemon=True
            )
            process.start()
            child.close()
            self._remotes.append(remote)
            self._workers.append(process)
        try:
            return self._ask_all([("build", None)] * len(env_fns))
        except BaseException:
            self.close()
            raise

    @staticmethod
    def _shared_spaces(layouts: list) -> tuple[spaces.Space, spaces.Space]:
        """The one observation and action space every agent of every copy must have."""
        obs_space, act_space = layouts[0][1][0], layouts[0][2][0]
        if not isinstance(obs_space, (spaces.Dict, spaces.Box)):
            raise TypeError(f"observation space must be a Dict of Boxes or a Box, got {obs_space}")
        if isinstance(obs_space, spaces.Dict):
            odd = [k for k, s in obs_space.spaces.items() if not isinstance(s, spaces.Box)]
            if odd:
                raise TypeError(f"observation space entries {odd} are not Boxes; the adapter stacks Boxes only")
        first = layouts[0][0][0]
        for k, (agents, obs_spaces, act_spaces) in enumerate(layouts):
            for agent, o, a in zip(agents, obs_spaces, act_spaces):
                if o != obs_space:
                    raise ValueError(
                        f"env copy {k}, agent {agent!r}: observation space differs from that of copy 0, "
                        f"agent {first!r}; one shared policy needs one space (got {o}, expected {obs_space})"
                    )
                if a != act_space:
                    raise ValueError(
                        f"env copy {k}, agent {agent!r}: action space {a} differs from {act_space} "
                        f"(copy 0, agent {first!r}); one shared policy needs one space"
                    )
        return obs_space, act_space

    # ------------------------------------------------------------------ workers
    def _receive(self, remote: Any) -> Any:
        status, payload = remote.recv()
        if status == "error":
            kind, message, trace = payload
            raise WorkerError(f"{kind} in env worker: {message}\n--- worker traceback ---\n{trace}")
        return payload

    def _ask_all(self, messages: Sequence[tuple[str, Any]], copies: Sequence[int] | None = None) -> list:
        """Send one message to each chosen worker, then collect every reply (workers run meanwhile)."""
        copies = range(len(self._remotes)) if copies is None else copies
        for k, message in zip(copies, messages):
            self._remotes[k].send(message)
        return self._collect(copies)

    def _collect(self, copies: Sequence[int]) -> list:
        """Every chosen worker's reply; after an error the other pipes are still drained, so
        they stay in step, and the first error is raised."""
        replies, error = [], None
        for k in copies:
            try:
                replies.append(self._receive(self._remotes[k]))
            except WorkerError as exc:
                error = error or exc
        if error is not None:
            raise error
        return replies

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        seeds = [self._seeds[lo] for lo in self.offsets[:-1]]
        options = [self._options[lo] for lo in self.offsets[:-1]]
        out = self._new_obs()
        if self.processes:
            replies = self._ask_all([("reset", (s, o)) for s, o in zip(seeds, options)])
            self._gather(out, [r[0] for r in replies])
            self.reset_infos = [info for r in replies for info in r[1]]
        else:
            self.reset_infos = [
                info
                for copy, lo, s, o in zip(self._copies, self.offsets, seeds, options)
                for info in copy.reset(s, o, out, lo)
            ]
        self._reset_seeds()
        self._reset_options()
        return self._as_obs(out)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset: slot ``i``'s seed is ``seed + i`` (modulo 2**64; copy ``k`` uses
        that of its first slot). ``seed`` is an integer from 0 to 2**64 - 1, else ``ValueError``
        naming it; None draws one at random. Returns the slots' seeds."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        seed = check_seed(seed, "SmartsVecEnv.seed(seed)")
        self._seeds = [derived_seed(seed, i) for i in range(self.num_envs)]
        return self._seeds

    def step_async(self, actions: np.ndarray) -> None:
        """Atomic over the copies: when any number is not finite (or not a real number), every
        copy checks its live agents' actions before any copy steps, so a refused step (an
        ``ActionError`` naming the copy and agents; a ``WorkerError`` carrying it with
        ``processes=True``) changes no copy. Actions of slots whose agent is not live are ignored."""
        actions = np.asarray(actions)
        expected = (self.num_envs, *self._agent_action_space.shape)
        if actions.shape != expected:
            raise ValueError(
                f"actions: expected one row per slot ({self.num_envs}) of the agents' action shape "
                f"{self._agent_action_space.shape}, i.e. shape {expected}; got shape {actions.shape}"
            )
        if self.normalize_actions:
            actions = (self._act_low + (np.clip(actions, -1.0, 1.0) + 1.0) * self._act_half_range).astype(
                self._agent_action_space.dtype
            )
        if actions.dtype.kind not in REAL_KINDS or not np.isfinite(actions).all():
            # Only now can a copy refuse its actions: ask all of them before any steps.
            if self.processes:
                self._ask_all([("check", actions[lo:hi]) for lo, hi in zip(self.offsets, self.offsets[1:])])
            else:
                for copy, lo, hi in zip(self._copies, self.offsets, self.offsets[1:]):
                    copy.check(actions[lo:hi])
        if self.processes:
            for remote, lo, hi in zip(self._remotes, self.offsets, self.offsets[1:]):
                remote.send(("step", actions[lo:hi]))
            self._waiting = True
        else:
            self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self.processes:
            self._waiting = False
            replies = self._collect(range(len(self._remotes)))
            out = self._new_obs()
            self._gather(out, [r[0] for r in replies])
            rewards = np.concatenate([r[1] for r in replies])
            dones = np.concatenate([r[2] for r in replies])
            infos = [info for r in replies for info in r[3]]
            for r, lo in zip(replies, self.offsets):
                if r[4] is not None:
                    self.reset_infos[lo : lo + len(r[4])] = r[4]
            return self._as_obs(out), rewards, dones, infos
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        actions, self._actions = self._actions, None
        out = self._new_obs()
        rewards = np.zeros(self.num_envs, np.float32)
        dones = np.zeros(self.num_envs, bool)
        infos: list[dict] = []
        for copy, lo, hi in zip(self._copies, self.offsets, self.offsets[1:]):
            copy_infos, reset_infos = copy.step(actions[lo:hi], out, rewards, dones, lo)
            infos.extend(copy_infos)
            if reset_infos is not None:
                self.reset_infos[lo:hi] = reset_infos
        return self._as_obs(out), rewards, dones, infos

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.processes:
            for remote in self._remotes:
                try:
                    if self._waiting:
                        remote.recv()
                    remote.send(("close", None))
                except (BrokenPipeError, EOFError, OSError):
                    pass
            for remote in self._remotes:
                try:
                    remote.recv()
                except (EOFError, OSError):
                    pass
            for process in self._workers:
                process.join(timeout=5)
                if process.is_alive():
                    process.terminate()
        else:
            for copy in self._copies:
                copy.env.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One frame per env copy (not per slot: a copy's agents share one scene)."""
        return self._per_copy("env_method", ("render", (), {}), range(len(self.offsets) - 1))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The attribute of each requested slot's env copy (slots of one copy share it)."""
        slots = list(self._get_indices(indices))
        copies = sorted({int(self._copy_of_slot[i]) for i in slots})
        values = dict(zip(copies, self._per_copy("get_attr", attr_name, copies)))
        return [values[int(self._copy_of_slot[i])] for i in slots]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set the attribute once on each env copy that owns one of the slots."""
        copies = sorted({int(self._copy_of_slot[i]) for i in self._get_indices(indices)})
        self._per_copy("set_attr", (attr_name, value), copies)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call the method once per env copy owning one of the slots; each slot gets its copy's result."""
        slots = list(self._get_indices(indices))
        copies = sorted({int(self._copy_of_slot[i]) for i in slots})
        results = dict(zip(copies, self._per_copy("env_method", (method_name, method_args, method_kwargs), copies)))
        return [results[int(self._copy_of_slot[i])] for i in slots]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        slots = list(self._get_indices(indices))
        copies = sorted({int(self._copy_of_slot[i]) for i in slots})
        wrapped = dict(zip(copies, self._per_copy("is_wrapped", wrapper_class, copies)))
        return [wrapped[int(self._copy_of_slot[i])] for i in slots]

    # ------------------------------------------------------------------ helpers
    def _per_copy(self, command: str, data: Any, copies: Sequence[int]) -> list:
        if self.processes:
            return self._ask_all([(command, data)] * len(copies), copies)
        envs = [self._copies[k].env for k in copies]
        if command == "get_attr":
            return [getattr(env, data) for env in envs]
        if command == "set_attr":
            return [setattr(env, data[0], data[1]) for env in envs]
        if command == "env_method":
            return [getattr(env, data[0])(*data[1], **data[2]) for env in envs]
        return [_is_wrapped(env, data) for env in envs]

    def _new_obs(self) -> dict:
        return _zeros(self._keys, self.observation_space, self.num_envs)

    def _gather(self, out: dict, parts: list[dict]) -> None:
        for k in self._keys:
            np.concatenate([p[k] for p in parts], out=out[k])

    def _as_obs(self, out: dict) -> VecEnvObs:
        return out if self._keys != [None] else out[None]
