"""The env's side of V2V messaging: the message part of the learners' actions, the networks that
carry it, and the received messages added to every step's observation batches.

With comms on, an agent's action is its driving action followed by the message components
(``smarts.comms.message_action_components``), and its observation gains ``messages`` and
``message_mask`` (``smarts.comms.received_observation_space``). Per step the env calls ``split``
before the simulation moves (so a bad message action changes nothing), then ``exchange`` once it
has moved: the learners' messages leave from where their senders are now, connected traffic
broadcasts its state, and every live agent (social ones included) receives what reaches it.
Social agents listen on their fixed channel and send nothing.

One ``V2VLink`` serves every episode of a simulation that has the same comms settings, in one call
per stage (``smarts.comms.network.V2VNetworks``); each episode keeps its own queues, rows, seed
and step, so no message crosses episodes and an episode hears what it would hear alone.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from smarts.comms import (
    CommsConfig,
    Received,
    message_action_components,
    message_action_space,
    received_observation_space,
    received_to_observation,
    split_message_action,
)
from smarts.comms.network import V2VNetworks
from smarts.core.errors import ActionError
from smarts.core.simulation import Simulation
from smarts.dynamics.action_spaces import REAL_KINDS
from smarts.sensors.suite import Batch


class V2VLink:
    """Message actions in, received messages out, for the agents of ``episodes`` (episodes of
    ``sim`` with this ``config``; agent indices are the simulation's)."""

    def __init__(self, config: CommsConfig, sim: Simulation, episodes: Sequence[int], driving_components: np.ndarray):
        """``driving_components[a]``: how many leading components of agent a's action drive it."""
        self.config = config
        self.sim = sim
        self.episodes = np.asarray(episodes, dtype=np.int64)
        self.network = V2VNetworks(config, sim.episode_capacity, [sim.episode_seed[b] for b in self.episodes])
        self._index = np.full(sim.episodes, -1, dtype=np.int64)  # simulation episode -> network episode
        self._index[self.episodes] = np.arange(len(self.episodes))
        self.base = self.episodes * sim.episode_capacity
        self.fixed_channels = np.zeros(len(sim.agent_ids), dtype=np.int64)  # by agent
        for b in self.episodes.tolist():
            view = sim.views[b]
            config.check_agents(view.agent_ids)
            self.fixed_channels[view.agents] = config.fixed_channels(view.agent_ids)
        self.tuned = self.fixed_channels.copy()  # channel each agent listens on, by agent index
        self.mine = np.isin(sim.agent_episode, self.episodes)  # by agent: its episode is served here
        self.driving_components = np.asarray(driving_components, dtype=np.int64)
        self.message_components = message_action_components(config)
        self._message_space = message_action_space(config)
        self._received_spaces = received_observation_space(config)

    # ------------------------------------------------------------------ spaces
    def action_space(self, driving: gym.spaces.Box) -> gym.spaces.Box:
        """The driving box followed by the message box, as one float32 box."""
        message = self._message_space
        return gym.spaces.Box(
            low=np.concatenate([driving.low, message.low]).astype(np.float32),
            high=np.concatenate([driving.high, message.high]).astype(np.float32),
            dtype=np.float32,
        )

    def observation_space(self, space: gym.spaces.Dict) -> gym.spaces.Dict:
        """``space`` with the received-messages keys added."""
        return gym.spaces.Dict({**space.spaces, **self._received_spaces})

    # ------------------------------------------------------------------ episode
    def _steps(self) -> np.ndarray:
        return self.sim.episode_step[self.episodes]

    def reset(self, episodes: np.ndarray) -> Received:
        """Empty the queues of ``episodes`` (simulation episodes served here), channels back to the
        fixed ones; what their live agents hear at step 0 (connected traffic, when latency is 0),
        in agent order. Call after the simulation reset them."""
        sim = self.sim
        e = self._index[episodes]
        self.network.reset(e, [sim.episode_seed[b] for b in episodes.tolist()])
        agents = np.flatnonzero(np.isin(sim.agent_episode, episodes))
        self.tuned[agents] = self.fixed_channels[agents]
        self.network.broadcast_traffic(self._steps(), self._tables(), sim.table, self.base, e)
        active = sim.active_agents[np.isin(sim.agent_episode[sim.active_agents], episodes)]
        return self._deliver(active)

    def _tables(self) -> list:
        return [self.sim.views[b].table for b in self.episodes.tolist()]

    def split(
        self, actions: Mapping[str, Any], ids: Sequence[str], agents: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Driving actions by id, payloads float32[n, message_size] and channels int64[n] of the
        agents ``ids`` (agent indices ``agents``). A wrong length or a non-finite message number
        raises ``ActionError`` naming the agents, before anything moves."""
        n = len(ids)
        if n == 0:
            return {}, np.zeros((0, self.config.message_size), dtype=np.float32), np.zeros(0, dtype=np.int64)
        k = self.driving_components[agents]
        width = len(self.message_components)
        k0 = int(k[0])
        if (k == k0).all():  # the usual case: one stacked array for everyone
            try:
                arr = np.asarray([actions[a] for a in ids])
            except (TypeError, ValueError):
                arr = None
            if arr is None or arr.dtype.kind not in REAL_KINDS or arr.shape != (n, k0 + width):
                self._raise_malformed(actions, ids, k)
            arr = arr.astype(np.float64, copy=False)
            control = dict(zip(ids, arr[:, :k0]))
            messages = arr[:, k0:]
        else:
            control, rows = {}, []
            for a, ka in zip(ids, k.tolist()):
                arr = self._one(actions[a], a, ka)
                control[a] = arr[:ka]
                rows.append(arr[ka:])
            messages = np.stack(rows)
        payloads, channels = split_message_action(self.config, messages, ids, self.fixed_channels[agents])
        return control, payloads, channels

    def split_array(self, actions: np.ndarray, agents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Payloads and channels of ``agents`` from their rows of an action array (each agent's
        message after its own driving components)."""
        width = len(self.message_components)
        ids = [self.sim.agent_ids[a] for a in agents.tolist()]
        cols = self.driving_components[agents][:, None] + np.arange(width)
        if agents.size and cols.max() >= actions.shape[1]:
            raise ActionError(
                f"expected action arrays of at least {int(cols.max()) + 1} columns (driving components, then "
                f"{width} message components), got {actions.shape[1]}",
                ids,
            )
        messages = np.asarray(actions[agents[:, None], cols], dtype=np.float64)
        return split_message_action(self.config, messages, ids, self.fixed_channels[agents])

    def exchange(self, senders: np.ndarray, payloads: np.ndarray, channels: np.ndarray) -> tuple[np.ndarray, Received]:
        """Send the senders' messages from their poses now, broadcast connected traffic and
        deliver to every live agent served here; returns those agents (ascending) and what each
        received. Call after the simulation step and before finished agents are removed."""
        sim, net = self.sim, self.network
        steps = self._steps()
        episode = self._index[sim.agent_episode[senders]]
        rows = sim.agent_row[senders] - self.base[episode]
        bad = net.send(steps, sim.table.data, self.base, episode, rows, channels, payloads)
        if bad >= 0:  # split_message_action has checked every value: only a broken row gets here
            raise ValueError(f"V2V: sender {sim.agent_ids[senders[bad]]} has no vehicle row")
        self.tuned[senders] = channels
        net.broadcast_traffic(steps, self._tables(), sim.table, self.base, np.arange(len(self.episodes)))
        active = sim.active_agents
        receivers = active[self.mine[active]]
        return receivers, self._deliver(receivers)

    def _deliver(self, receivers: np.ndarray) -> Received:
        sim = self.sim
        episode = self._index[sim.agent_episode[receivers]]
        rows = sim.agent_row[receivers] - self.base[episode]
        return self.network.deliver(self._steps(), sim.table.data, self.base, episode, rows, self.tuned[receivers])

    @staticmethod
    def merge(batches: list[Batch], agents: np.ndarray, received: Received) -> None:
        """Add ``messages`` and ``message_mask`` to each batch; ``received`` is in the order of
        ``agents`` (sorted agent indices, of which each batch holds a subset)."""
        obs = received_to_observation(received)
        for members, batch in batches:
            if members.shape == agents.shape:  # the one interface group holds every agent
                batch.update(obs)
            else:
                at = np.searchsorted(agents, members)
                batch.update((key, value[at]) for key, value in obs.items())

    # ------------------------------------------------------------------ errors
    def _one(self, action: Any, agent: str, k: int) -> np.ndarray:
        try:
            arr = np.asarray(action)
            if arr.dtype.kind not in REAL_KINDS:
                raise TypeError(arr.dtype)
            arr = arr.astype(np.float64, copy=False)
        except (TypeError, ValueError):
            raise ActionError(
                f"{agent}: action {action!r} is not an array of numbers; expected {self._expected(k)}",
                [agent],
            ) from None
        if arr.shape != (k + len(self.message_components),):
            raise ActionError(f"{agent}: action has shape {arr.shape}; expected {self._expected(k)}", [agent])
        return arr

    def _raise_malformed(self, actions: Mapping[str, Any], ids: Sequence[str], k: np.ndarray) -> None:
        for a, ka in zip(ids, k.tolist()):
            self._one(actions[a], a, ka)
        raise ActionError(f"malformed actions for agents {list(ids)}", list(ids))  # pragma: no cover

    def _expected(self, k: int) -> str:
        names = self.message_components
        return (
            f"shape ({k + len(names)},): {k} driving components followed by {len(names)} message "
            f"components ({names[0]}..{names[-1]})"
        )
