"""The provider protocol: whoever moves vehicles owns rows of the vehicle table.

The agent provider (controllers for action spaces), traffic engines, replay and signals all plug into
the step loop through this protocol. Providers write their rows of the table in place; there is no
merge copy. Ownership is the ``owner`` column: a hand-over rewrites it and tells both providers.

A simulation runs B episodes (``smarts.core.simulation``). Most providers belong to one episode:
they are given its ``EpisodeView`` as ``sim`` (its block of the table with rows from 0, its clock,
seed, map, signals and agents), so they are written as for a single simulation and run unchanged
whatever B is. A kind of episode provider may name a ``batch_stage``: a class built once per
simulation with every such provider of every episode, ``stage(sim, [(episode, provider), ...])``,
that steps them all at once (``step(sim, dt)``, ``after_reset(sim, episodes)``); the simulation
then never calls those providers' own ``step``. The agent provider is a *batch provider*: it is
given the whole simulation and global rows, and resets per episode (``reset_episode(sim, b,
agents)`` then, after the episode's providers have reset, ``start_episode(sim, b, agents)``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from smarts.core.simulation import Simulation


@runtime_checkable
class Provider(Protocol):
    name: str
    provider_id: int  # assigned by the simulation when the provider is added

    def reset(self, sim: "Simulation") -> None:
        """Create this provider's vehicles for a new episode (the table is empty of its rows; it
        forgets every row it drove)."""

    def start(self, sim: "Simulation") -> None:
        """Second phase of a reset, after every provider's ``reset``: take over vehicles that
        other providers created."""

    def check_actions(self, sim: "Simulation", actions: dict, agents: "np.ndarray | None") -> None:
        """Optional. Raise ``ActionError`` if ``actions`` (agent id -> action) cannot be applied to
        this provider's agents (``agents``: agent indices to check; None: every active agent),
        changing nothing. The simulation calls it for every provider before a step changes
        anything, so a refused step leaves the whole simulation as it was."""

    def step(self, sim: "Simulation", dt: float) -> None:
        """Advance the rows this provider owns by ``dt`` seconds, writing the table in place."""

    def can_accept(self, sim: "Simulation", rows: np.ndarray) -> np.ndarray:
        """bool per row: whether this provider can take the vehicle over."""

    def accept(self, sim: "Simulation", rows: np.ndarray) -> None:
        """Start driving rows that were just handed to this provider."""

    def release(self, sim: "Simulation", rows: np.ndarray) -> None:
        """Stop driving rows that are being handed to another provider or removed."""

    def close(self) -> None:
        """Free external resources (processes, physics clients)."""


class ProviderBase:
    """Defaults for optional parts of the protocol: accept nothing, hold no resources."""

    name = "provider"
    provider_id = -1

    def reset(self, sim: "Simulation") -> None:
        pass

    def start(self, sim: "Simulation") -> None:
        pass

    def check_actions(self, sim: "Simulation", actions: dict, agents: "np.ndarray | None") -> None:
        pass

    def step(self, sim: "Simulation", dt: float) -> None:
        pass

    def can_accept(self, sim: "Simulation", rows: np.ndarray) -> np.ndarray:
        return np.zeros(len(rows), dtype=bool)

    def accept(self, sim: "Simulation", rows: np.ndarray) -> None:
        raise NotImplementedError(f"provider {self.name!r} does not accept vehicles")

    def release(self, sim: "Simulation", rows: np.ndarray) -> None:
        pass

    def close(self) -> None:
        pass
