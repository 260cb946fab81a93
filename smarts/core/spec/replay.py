"""The ``replay:`` section of a scenario: which recorded dataset to replay, and how.

Plain data every layer reads; ``smarts.scenario.replay`` reads it from YAML and checks each field,
``smarts.replay`` loads the recording and drives its vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

REPLAY_FORMATS = ("ngsim", "argoverse2", "waymo")
REACTIVE_MODES = ("off", "interaction", "always")
"""``off``: recorded vehicles always follow their tracks; ``interaction``: one switches to the
built-in traffic model (IDM/MOBIL) the first time an agent comes within ``reactive_distance``;
``always``: every recorded vehicle is driven by the traffic model from the moment it enters."""
COORDINATES = ("local", "global")
"""NGSIM's column pairs: Local_X/Local_Y (metres along and across the study area) or
Global_X/Global_Y (state plane coordinates)."""
REPLAY_MAP = "replay"
"""A scenario's ``map`` naming the dataset's own map (Argoverse 2's map JSON, Waymo's map features)."""


@dataclass
class ReplaySpec:
    format: str
    path: str
    """A file (NGSIM CSV, Waymo TFRecord) or folder (Argoverse 2 scenario), relative to the scenario
    file's folder."""
    start: float | None = None
    """Seconds after the recording's first frame at which the episode starts; None: 0, or the entry
    of the latest-entering taken-over vehicle."""
    duration: float | None = None
    """Seconds of recording replayed from ``start``; None: to the end of the recording."""
    vehicles: list[str] | None = None
    """Recorded vehicle ids to replay; None: all of them."""
    take_over: dict[str, str] = field(default_factory=dict)
    """Agent id -> recorded vehicle id: the agent starts in that vehicle's state at ``start`` and
    its goal is the vehicle's last recorded position."""
    reactive: str = "off"
    reactive_distance: float = 10.0
    """Metres between an agent's centre and a recorded vehicle's at which they interact."""
    coordinates: str = "local"
    swap_xy: bool = False
    flip_y: bool = False
    offset: tuple[float, float] = (0.0, 0.0)
    """Metres added to every position after swapping and flipping (lines the data up with the map)."""
    scenario: str | None = None
    """Which part of the recording: for Waymo the scenario id (or 0-based record index) in the
    TFRecord file (None: the first); for NGSIM the ``Location`` of a file holding several sites."""
