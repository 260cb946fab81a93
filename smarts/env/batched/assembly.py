"""What the batched backend refuses, and why: the field that needs another path.

Every scenario runs on the one simulation core (``smarts.core.simulation``); a batch of them is
that core with B > 1 episodes. What cannot share one process with other episodes is refused here
with a ``BatchedSetupError`` naming the scenario and the field, so a run never silently falls
back to something else.
"""

from __future__ import annotations

from smarts.core.errors import ScenarioError
from smarts.scenario import ScenarioSpec


class BatchedSetupError(ScenarioError):
    """A scenario (or option) the batched backend cannot step; the message says what to use."""


def check_batchable(spec: ScenarioSpec) -> None:
    """Raise ``BatchedSetupError`` naming the field when ``spec`` needs the per-env path."""
    where = spec.source
    if spec.traffic is not None and spec.traffic.engine == "sumo":
        raise BatchedSetupError(
            f"{where}: traffic.engine: sumo runs one simulation per process (libsumo) and cannot be "
            "batched; use the per-env backend (--backend per_env) or engine: builtin"
        )
