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
    def __init__(self, interfaces: Sequence[AgentInterface]):
        """``interfaces[i]`` is agent i's interface (agent indices as in ``Simulation``)."""
        groups: dict[AgentInterface, int] = {}
        for interface in interfaces:
            groups.setdefault(interface, len(groups))
        if not groups:
            groups[AgentInterface()] = 0
        self.builders = [ObservationBuilder(interface, stream=g) for interface, g in groups.items()]
        self.group_of = np.array([groups[i] for i in interfaces], dtype=np.int64)

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
