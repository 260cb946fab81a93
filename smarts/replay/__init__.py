"""Recorded traffic from real-world datasets (NGSIM, Argoverse 2, Waymo Open Motion), replayed.

Readers turn each format into a :class:`Recording` (tracks as flat arrays); the
:class:`ReplayProvider` drives the recorded vehicles through the simulation, lets agents take
vehicles over and hands vehicles to the traffic model when they turn reactive.
"""

from __future__ import annotations

from smarts.lazy_exports import lazy_exports

_EXPORTS = {
    "ReplayPlan": "load",
    "TakeOver": "load",
    "load_recording": "load",
    "plan_replay": "load",
    "read_recording": "load",
    "replay_road_map": "load",
    "take_over_mission": "load",
    "ReplayProvider": "provider",
    "table_id": "provider",
    "DatasetMap": "recording",
    "Recording": "recording",
}
"""Public name -> submodule, imported on first use: the ``smarts replay`` commands import this
package, and their ``--help`` needs none of the readers (about 1 s of imports)."""

__all__ = sorted(_EXPORTS)


__getattr__ = lazy_exports(__name__, _EXPORTS, globals())
