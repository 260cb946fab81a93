"""Policy resolvers: how the simulator turns a locator into a policy without importing policies.

Social agents in a scenario (``policy: zoo:keep-lane``) and the benchmark runner name policies by
locator. The simulator sits below ``agents/`` and ``zoo/`` and never imports them; it asks a
*resolver*, a callable ``resolver(locator, **kwargs) -> policy``. A caller may pass its own
(``policy_resolver=`` on ``DrivingParallelEnv`` and on the benchmark runner); otherwise
:func:`default_resolver` finds the installed ones through the ``smarts.policies`` entry-point group
of the installed packages. Entry points are read from the installed metadata, so worker processes
and Ray workers resolve the same locators without anything being pickled; an explicit resolver
that goes to other processes must be picklable (a module-level function).

Routing of :func:`default_resolver`: a locator ``scheme:rest`` goes to the entry point named
``scheme`` (``zoo:drive`` to ``zoo``); any other locator (a checkpoint path, a bare zoo name) to
the one named ``default``. This project registers the zoo under both (``pyproject.toml``). A
resolver raises ``ValueError`` for a locator it does not know, naming the ones it knows.
"""

from __future__ import annotations

import functools
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Protocol

import numpy as np

from smarts.core.errors import NoResolverError

ENTRY_POINT_GROUP = "smarts.policies"
FALLBACK = "default"
"""The entry point that resolves locators without a registered scheme."""


class Policy(Protocol):
    """What the simulator needs of a policy: batched actions in a named action space.

    ``act`` maps observations ``{key: [n, ...]}`` of n agents to actions ``[n, k]``;
    ``action_space`` names a simulator action space (``relative_target_pose`` ...). Optional:
    ``controller`` (``direct`` or ``lane_relative``), ``interface`` and ``lane_relative`` (the
    settings the policy was trained with, as the simulator's objects or their plain-data form,
    validated where the env is built), ``dt`` (set to the scenario's step), ``seed(int)``,
    ``source`` (the checkpoint file it was loaded from: errors name it, and the benchmark's resume
    keys its episodes by that file's contents), ``batching`` (how the benchmark may share it
    between episodes stepped together: ``rows``, ``episodes`` or ``instances``, see
    ``smarts.benchmark.batching.BATCHING``; absent: each of its episodes runs alone) and, with
    ``episodes``, ``act_episodes(obs, counts)`` (``act`` of several episodes' stacked rows in one
    call, equal bit for bit to one ``act`` per episode)."""

    action_space: str

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray: ...


class PolicyResolver(Protocol):
    def __call__(self, locator: str, /, **kwargs: Any) -> Policy: ...


@functools.cache
def installed_entry_points() -> dict[str, EntryPoint]:
    """Resolver entry points by name (the first installed one of each name), read once per process."""
    found: dict[str, EntryPoint] = {}
    for point in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(point.name, point)
    return found


def default_resolver(locator: str, /, **kwargs: Any) -> Policy:
    """Resolve ``locator`` with the installed resolver of its scheme, else the ``default`` one."""
    points = installed_entry_points()
    scheme, colon, _ = locator.partition(":")
    name = scheme if colon and scheme in points and scheme != FALLBACK else FALLBACK
    if name not in points:
        schemes = ", ".join(f"{n}:" for n in sorted(points) if n != FALLBACK) or "none"
        raise NoResolverError(
            f"no policy resolver for {locator!r}: installed schemes: {schemes}, and no {FALLBACK!r} resolver "
            f"(packages register them in the {ENTRY_POINT_GROUP!r} entry-point group; "
            "reinstall this project with `pip install -e .`)"
        )
    resolver = _load_resolver(points[name])
    return resolver(locator, **kwargs)


def _load_resolver(point: EntryPoint) -> PolicyResolver:
    """The entry point's resolver (imported once; later loads are lookups). A folder in the current
    directory named like the resolver's package (``zoo/``, say an output folder) comes first on
    ``python -m``'s search path and hides the installed package: said in so many words."""
    import sys

    try:
        return point.load()
    except (ImportError, AttributeError) as err:
        package = point.module.split(".")[0]
        found = sys.modules.get(package)
        if found is not None and getattr(found, "__file__", None) is None:  # a namespace package: a bare folder
            folders = ", ".join(str(f) for f in getattr(found, "__path__", [])) or "?"
            raise NoResolverError(
                f"the policy resolver {point.name!r} ({point.value}) could not be loaded ({err}): the package "
                f"{package!r} was found as the folder {folders}, which hides the installed one (Python looks in "
                "the current directory first); run from another directory or rename that folder"
            ) from None
        raise NoResolverError(f"the policy resolver {point.name!r} ({point.value}) could not be loaded: {err}") from err


def resolve_policy(locator: str, resolver: PolicyResolver | None = None, **kwargs: Any) -> Policy:
    """The policy ``locator`` names: from ``resolver`` when given, else :func:`default_resolver`.

    ``kwargs`` go to the resolver (options of the policy, e.g. ``dt``). A resolver of your own
    that knows only some locators can hand the others to :func:`default_resolver`."""
    return (resolver or default_resolver)(locator, **kwargs)
