"""The env's side of V2V messaging: the message part of the learners' actions, the network that
carries it, and the received messages added to every step's observation batches.

With comms on, an agent's action is its driving action followed by the message components
(``smarts.comms.message_action_components``), and its observation gains ``messages`` and
``message_mask`` (``smarts.comms.received_observation_space``). Per step the env calls ``split``
before the simulation moves (so a bad message action changes nothing), then ``exchange`` once it
has moved: the learners' messages leave from where their senders are now, connected traffic
broadcasts its state, and every live agent (social ones included) receives what reaches it.
Social agents listen on their fixed channel and send nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from smarts.comms import (
    CommsConfig,
    Received,
    V2VNetwork,
    message_action_components,
    message_action_space,
    received_observation_space,
    received_to_observation,
    split_message_action,
)
from smarts.core.simulation import Simulation
from smarts.core.errors import ActionError
from smarts.dynamics.action_spaces import REAL_KINDS
from smarts.sensors.suite import Batch


class V2VLink:
    """Message actions in, received messages out, for one simulation's agents."""

    def __init__(self, config: CommsConfig, sim: Simulation, driving_components: Sequence[int]):
        """``driving_components[i]``: how many leading components of agent i's action drive it."""
        config.check_agents(sim.agent_ids)
        self.config = config
        self.network = V2VNetwork(config, sim.table.capacity, sim.seed)
        self.fixed_channels = config.fixed_channels(sim.agent_ids)
        self.tuned = self.fixed_channels.copy()  # channel each agent listens on, by agent index
        self.driving_components = np.asarray(driving_components, dtype=np.int64)
        self.message_components = message_action_components(config)
        self._message_space = message_action_space(config)
        self._received_spaces = received_observation_space(config)
        self._no_payloads = np.zeros((0, config.message_size), dtype=np.float32)
        self._no_channels = np.zeros(0, dtype=np.int64)

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
    def reset(self, sim: Simulation) -> Received:
        """Empty queues, channels back to the fixed ones; what the live agents hear at step 0
        (connected traffic, when latency is 0). Call after ``sim.reset``."""
        self.network.reset(sim.seed)
        self.tuned[:] = self.fixed_channels
        self.network.broadcast_traffic(0, sim.table)
        return self.network.deliver(0, sim.table, sim.active_rows, self.tuned[sim.active_agents])

    def split(
        self, actions: Mapping[str, Any], ids: Sequence[str], agents: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Driving actions by id, payloads float32[n, message_size] and channels int64[n] of the
        agents ``ids`` (agent indices ``agents``). A wrong length or a non-finite message number
        raises ``ActionError`` naming the agents, before anything moves."""
        n = len(ids)
        if n == 0:
            return {}, self._no_payloads, self._no_channels
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
        payloads, channels = split_message_action(
            self.config, messages, ids, self.fixed_channels[agents]
        )
        return control, payloads, channels

    def exchange(
        self, sim: Simulation, senders: np.ndarray, payloads: np.ndarray, channels: np.ndarray
    ) -> Received:
        """Send the senders' messages from their poses now, broadcast connected traffic and
        deliver to every live agent (in ``sim.active_agents`` order). Call after ``sim.step`` and
        before finished agents are removed."""
        step, table, net = sim.step_count, sim.table, self.network
        net.send(step, table, sim.agent_row[senders], channels, payloads)
        self.tuned[senders] = channels
        net.broadcast_traffic(step, table)
        return net.deliver(step, table, sim.active_rows, self.tuned[sim.active_agents])

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
                f"{agent}: action {action!r} is not an array of numbers; expected "
                f"{self._expected(k)}",
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
