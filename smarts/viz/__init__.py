"""The diagnostic web viewer: live and recorded episodes in a browser (``smarts viz``).

``WatchedEnv`` records a ``DrivingParallelEnv``'s episodes (``smarts.viz.recording``) and/or
streams them to a running viewer; ``smarts.viz.server`` serves the page, recordings and benchmark
episode logs. Nothing below this package imports it. Names load on first use, so the ``smarts``
command line stays quick to start.
"""

from __future__ import annotations

_EXPORTS = {
    "Recording": "smarts.viz.recording",
    "read_recording": "smarts.viz.recording",
    "write_recording": "smarts.viz.recording",
    "WatchedEnv": "smarts.viz.watch",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'smarts.viz' has no attribute {name!r}")
