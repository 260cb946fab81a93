"""The simulator's error types, in one module every layer can import.

Each is a ``ValueError`` (bad input the caller can fix: a map, a scenario field, an action, an
interface, an episode log, a policy locator or its benchmark setup) or a ``RuntimeError`` (a tool
or worker that failed), so an ``except ValueError`` written for one keeps catching it. Messages
name the file or field at fault and what was expected.

``MapError`` and ``NoRouteError`` are defined with the maps (``smarts.maps.errors``, the one
package below core) and are the same classes here. They load on first use, so importing this
module stays cheap (``smarts.maps`` compiles its numba kernels on import).
"""

from __future__ import annotations

from typing import Sequence

_MAP_ERRORS = ("MapError", "NoRouteError")

__all__ = [
    "ActionError",
    "AgentSetupError",
    "InterfaceError",
    "LogError",
    "MapError",  # noqa: F822  (from smarts.maps.errors on first use: __getattr__ below)
    "MetricParamsError",
    "NetconvertError",
    "NoResolverError",
    "NoRouteError",  # noqa: F822
    "OutputError",
    "ReplayError",
    "ScenarioError",
    "WorkerError",
]


class ScenarioError(ValueError):
    """A scenario file, field or name is invalid; the message names where and what was expected.

    Also raised for invalid traffic and comms sections, and for traffic that does not fit its map.
    """


class ReplayError(ValueError):
    """A recorded dataset (NGSIM CSV, Argoverse 2 parquet or map JSON, Waymo TFRecord) that cannot
    be read or replayed; the message names the file, the record or column, and what was expected."""


class NetconvertError(RuntimeError):
    """netconvert failed on a generated map; the message carries its stderr."""


class ActionError(ValueError):
    """An action that cannot be applied; ``agent_ids`` lists the agents whose actions are bad, so a
    caller can drop those agents without touching the others."""

    def __init__(self, message: str, agent_ids: Sequence[str] = ()):
        super().__init__(message)
        self.agent_ids = list(agent_ids)


class InterfaceError(ValueError):
    """An invalid interface field; ``path`` is the dotted field (``interface.lidar.rays``)."""

    def __init__(self, path: str, problem: str):
        self.path, self.problem = path, problem
        super().__init__(f"{path}: {problem}")


class ConfigError(ValueError):
    """A training config (YAML or command-line override) is invalid; the message names the file or
    flag and the field."""


class AgentSetupError(ValueError):
    """A policy cannot be benchmarked as declared (unknown action space or controller, one the
    suite does not host, an invalid interface or lane-relative settings); the message names the
    agent (and the file it came from)."""


class NoResolverError(ValueError):
    """No installed resolver handles a locator (the package that registers it is not installed)."""


class MetricParamsError(ValueError):
    """A metrics config file or value is invalid; the message names the file and key."""


class LogError(ValueError):
    """An episode log is malformed; the message names the file, agent and column at fault."""

    def __init__(
        self,
        problem: str,
        *,
        source: str | None = None,
        agent: str | None = None,
        column: str | None = None,
    ) -> None:
        self.source = source or "<in-memory log>"
        self.agent = agent
        self.column = column
        where = [self.source]
        if agent is not None:
            where.append(f"agent {agent!r}")
        if column is not None:
            where.append(f"column {column!r}")
        self.problem = problem
        super().__init__(f"{': '.join(where)}: {problem}")

    def __reduce__(self):
        # Keep the structured fields when the error crosses a process boundary (parallel runner).
        return (
            _rebuild_log_error,
            (self.problem, self.source, self.agent, self.column),
        )


def _rebuild_log_error(problem: str, source: str, agent: str | None, column: str | None) -> LogError:
    return LogError(problem, source=source, agent=agent, column=column)


class OutputError(ValueError):
    """An output folder that cannot take a run's files (it refuses writes, it cannot be made, its
    disk has too little free space); the message names the folder. Checked before a run starts."""


class WorkerError(RuntimeError):
    """An exception raised inside an env worker process (the message carries its traceback)."""


def __getattr__(name: str):
    if name in _MAP_ERRORS:
        from smarts.maps import errors

        return getattr(errors, name)
    raise AttributeError(f"module 'smarts.core.errors' has no attribute {name!r}")
