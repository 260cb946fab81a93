"""Recorded traffic from real-world datasets (NGSIM, Argoverse 2, Waymo Open Motion), replayed.

Readers turn each format into a :class:`Recording` (tracks as flat arrays); the
:class:`ReplayProvider` drives the recorded vehicles through the simulation, lets agents take
vehicles over and hands vehicles to the traffic model when they turn reactive.
"""

from smarts.replay.load import (
    ReplayPlan,
    TakeOver,
    load_recording,
    plan_replay,
    read_recording,
    replay_road_map,
    take_over_mission,
)
from smarts.replay.provider import ReplayProvider, table_id
from smarts.replay.recording import DatasetMap, Recording

__all__ = [
    "DatasetMap",
    "Recording",
    "ReplayPlan",
    "ReplayProvider",
    "TakeOver",
    "load_recording",
    "plan_replay",
    "read_recording",
    "replay_road_map",
    "table_id",
    "take_over_mission",
]
