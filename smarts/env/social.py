"""Social agents: scenario agents driven by policies (``policy: zoo:keep-lane``), not the learner.

They live in the simulation like every agent (same missions, events, observation and action
machinery); the env asks their policies for actions from the observations of the previous step
and merges them with the learners' actions. Agents sharing a policy locator are batched: each
policy is called once per step for all its agents of every episode. Locators become policies
through a resolver (``smarts.core.policies``): the env's own, or the installed default (the zoo),
so the simulator never imports the policies it runs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from smarts.core.policies import PolicyResolver, resolve_policy
from smarts.core.simulation import Simulation
from smarts.scenario import ScenarioSpec


class SocialAgents:
    def __init__(self, specs: Sequence[ScenarioSpec], sim: Simulation, resolver: PolicyResolver | None = None):
        """``specs[b]``: episode ``b``'s scenario; ``resolver`` turns each agent's ``policy``
        locator into a policy (None: the default)."""
        self.is_social = np.zeros(len(sim.agent_ids), dtype=bool)
        by_locator: dict[tuple[str, float], list[int]] = {}
        where: dict[int, tuple[ScenarioSpec, int]] = {}
        for b, spec in enumerate(specs):
            first = int(sim.episode_agent_start[b])
            for i, agent in enumerate(spec.agents):
                locator = getattr(agent, "policy", None)
                if locator:
                    a = first + i
                    by_locator.setdefault((locator, spec.step_length), []).append(a)
                    where[a] = (spec, i)
                    self.is_social[a] = True
        self.groups: list[tuple[object, np.ndarray]] = []
        for (locator, dt), members in by_locator.items():
            spec, i = where[members[0]]
            try:
                policy = resolve_policy(locator, resolver)
            except ValueError as err:
                raise ValueError(f"{spec.source}: agents[{i}].policy: {err}") from None
            if hasattr(policy, "dt"):
                policy.dt = dt
            for a in members:
                spec, i = where[a]
                if spec.agents[i].action_space != policy.action_space:
                    raise ValueError(
                        f"{spec.source}: agents[{i}].action_space: policy {locator!r} acts in "
                        f"{policy.action_space}, got {spec.agents[i].action_space}"
                    )
            self.groups.append((policy, np.array(members, dtype=np.int64)))

        self.any = bool(self.is_social.any())
        """Whether any agent is social (read every step)."""

    def actions_of(self, agents: np.ndarray, observations: dict[str, np.ndarray]) -> np.ndarray:
        """float64[n, k] actions of the live social ``agents`` (ascending); ``observations[key][a]``
        is agent ``a``'s last observation. One ``act`` call per policy."""
        out = None
        for policy, members in self.groups:
            mine = np.flatnonzero(np.isin(agents, members))
            if mine.size == 0:
                continue
            acts = np.asarray(policy.act({k: v[agents[mine]] for k, v in observations.items()}), dtype=np.float64)
            if out is None:
                out = np.zeros((len(agents), acts.shape[1]))
            elif acts.shape[1] > out.shape[1]:
                out = np.pad(out, ((0, 0), (0, acts.shape[1] - out.shape[1])))
            out[mine, : acts.shape[1]] = acts
        return out if out is not None else np.zeros((len(agents), 0))
