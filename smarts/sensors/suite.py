"""Observations of agents with different interfaces: one batched builder per interface group.

Agents with equal interfaces share one observation space and one ``ObservationBuilder``; a step
runs one pass per group present, so a scenario where every agent has the same interface (the usual
case) costs exactly one batched build.
"""

from __future__ import annotations

from collections.abc import Sequence

import gymnasium as gym
import numpy as np

from smarts.core.simulation import Simulation
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import ObservationBuilder

Batch = tuple[np.ndarray, dict[str, np.ndarray]]
"""Agent indices of one group and their observations ``{key: array[n, ...]}`` in that order."""


class ObservationSuite:
    def __init__(
        self,
        interfaces: Sequence[AgentInterface],
        keys: Sequence | None = None,
        episode_of: Sequence[int] | None = None,
    ):
        """``interfaces[i]`` is agent i's interface (agent indices as in ``Simulation``);
        ``keys[i]`` (default: the interface) groups agents whose observations have the same
        layout, when something else adds to them (V2V messages in some episodes only);
        ``episode_of[i]``: agent i's episode (its groups' noise streams are numbered per episode,
        so an episode draws the same noise alone or among others)."""
        keys = list(interfaces) if keys is None else list(keys)
        groups: dict = {}
        first: dict = {}
        for interface, key in zip(interfaces, keys):
            if key not in groups:
                groups[key] = len(groups)
                first[key] = interface
        if not groups:
            groups[AgentInterface()] = 0
            first[AgentInterface()] = AgentInterface()
        self.builders = [ObservationBuilder(first[key], stream=g) for key, g in groups.items()]
        self.group_of = np.array([groups[k] for k in keys], dtype=np.int64)
        if episode_of is not None:
            ranks: dict[int, list[int]] = {}
            for g, b in zip(self.group_of.tolist(), list(episode_of)):
                seen = ranks.setdefault(int(b), [])
                if g not in seen:
                    seen.append(g)
            for b, order in ranks.items():
                for rank, g in enumerate(order):
                    if self.builders[g].lidar is not None:
                        self.builders[g].lidar.episode_streams[b] = rank

    def space(self, agent: int) -> gym.spaces.Dict:
        return self.builders[self.group_of[agent]].space

    def interface(self, agent: int) -> AgentInterface:
        return self.builders[self.group_of[agent]].interface

    def build(self, sim: Simulation, agents: np.ndarray) -> list[Batch]:
        """One batch per interface group among ``agents`` (empty groups left out)."""
        if len(self.builders) == 1:
            return [(agents, self.builders[0].build(sim, agents))]
        group = self.group_of[agents]
        out = []
        for g, builder in enumerate(self.builders):
            members = agents[group == g]
            if members.size:
                out.append((members, builder.build(sim, members)))
        return out
