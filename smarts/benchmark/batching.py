"""Which benchmark episodes may share a simulation, decided without the simulator: a policy's
declared ``batching`` and what makes a scenario run alone. The runner's planning reads these in the
process that only plans (importing the batched loop, the recorder and the maps' routing there cost
over half a second); :mod:`smarts.benchmark.batched` steps the batches."""

from __future__ import annotations

from typing import Any

from smarts.core.policies import resolve_policy
from smarts.scenario import ScenarioSpec
from smarts.sensors.interface import AgentInterface

__all__ = ["BATCHING", "batching_mode", "solo_reason"]

BATCHING = {
    "rows": "act is row by row and keeps no state: one instance, one call per step for the rows of "
    "every episode stacked (a row's action does not depend on the other rows, bit for bit)",
    "episodes": "keeps no state, but a call's results may depend on which rows it holds (a network "
    "whose matrix products round differently by batch size): one instance, one call per episode",
    "instances": "keeps state across calls (or draws random numbers): an instance per episode, "
    "loaded and seeded as for a lone episode, one call per episode",
}
"""``policy.batching`` values: how the benchmark may share a policy between the episodes of a batch."""


def batching_mode(policy: Any) -> str | None:
    """The policy's declared ``batching`` (:data:`BATCHING`), or None (run its episodes alone)."""
    mode = getattr(policy, "batching", None)
    return mode if mode in BATCHING else None


_SOCIAL_MODES: dict[str, str | None] = {}


def _social_mode(locator: str) -> str | None:
    """A social agent's policy's batching (resolved as the env resolves it: the installed default)."""
    if locator not in _SOCIAL_MODES:
        try:
            _SOCIAL_MODES[locator] = batching_mode(resolve_policy(locator))
        except Exception:  # noqa: BLE001 - the lone episode reports it
            _SOCIAL_MODES[locator] = None
    return _SOCIAL_MODES[locator]


def solo_reason(spec: ScenarioSpec, observation: AgentInterface | None) -> str | None:
    """Why an episode of ``spec`` (already in the policy's action space) cannot share a simulation
    with others, or None when it can."""
    if spec.traffic is not None and spec.traffic.engine == "sumo":
        return "SUMO traffic (libsumo holds one simulation per process)"
    social = [a.policy for a in spec.agents if a.is_social]
    if any(_social_mode(locator) != "rows" for locator in social):
        return "a social agent's policy cannot be shared between episodes"
    if observation is None:
        interfaces = {repr(a.interface) for a in spec.agents if not a.is_social}
        if len(interfaces) > 1:
            return "its learning agents observe through different interfaces"
    return None
