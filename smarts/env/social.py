"""Social agents: scenario agents driven by policies (``policy: zoo:keep-lane``), not the learner.

They live in the simulation like every agent (same missions, events, observation and action
machinery); the env asks their policies for actions from the observations of the previous step
and merges them with the learner's actions. Agents sharing a policy locator are batched. Locators
become policies through a resolver (``smarts.core.policies``): the env's own, or the installed
default (the zoo), so the simulator never imports the policies it runs.
"""

from __future__ import annotations

import numpy as np

from smarts.core.policies import PolicyResolver, resolve_policy
from smarts.core.simulation import Simulation
from smarts.scenario import ScenarioSpec


class SocialAgents:
    def __init__(self, spec: ScenarioSpec, sim: Simulation, resolver: PolicyResolver | None = None):
        """``resolver`` turns each agent's ``policy`` locator into a policy (None: the default)."""
        self.is_social = np.zeros(len(sim.agent_ids), dtype=bool)
        by_locator: dict[str, list[int]] = {}
        for i, agent in enumerate(spec.agents):
            locator = getattr(agent, "policy", None)
            if locator:
                by_locator.setdefault(locator, []).append(i)
                self.is_social[i] = True
        self.groups = []
        for locator, members in by_locator.items():
            try:
                policy = resolve_policy(locator, resolver)
            except ValueError as err:
                raise ValueError(f"{spec.source}: agents[{members[0]}].policy: {err}") from None
            if hasattr(policy, "dt"):
                policy.dt = spec.step_length
            for i in members:
                if spec.agents[i].action_space != policy.action_space:
                    raise ValueError(
                        f"{spec.source}: agents[{i}].action_space: policy {locator!r} acts in "
                        f"{policy.action_space}, got {spec.agents[i].action_space}"
                    )
            self.groups.append((policy, np.array(members, dtype=np.int64)))

    @property
    def any(self) -> bool:
        return bool(self.is_social.any())

    def actions(self, sim: Simulation, batch: dict[str, np.ndarray], agents: np.ndarray) -> dict[str, np.ndarray]:
        """Actions of the live social agents; ``batch`` holds observations of ``agents``."""
        out: dict[str, np.ndarray] = {}
        for policy, members in self.groups:
            live = np.flatnonzero(np.isin(agents, members) & sim.agent_active[agents])
            if live.size == 0:
                continue
            acts = policy.act({k: v[live] for k, v in batch.items()})
            for j, a in zip(live.tolist(), acts):
                out[sim.agent_ids[agents[j]]] = a
        return out
