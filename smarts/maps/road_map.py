"""A road network compiled to flat arrays.

Every per-step map query (nearest lane, lane coordinates, on-road test) runs on these arrays for all
vehicles at once, so the map is stored as a struct of arrays rather than as Python lane objects.

Conventions (used across the whole simulator):
- Units are SI; positions are metres in the map frame (the SUMO network frame after its netOffset).
- Heading is in radians, 0 along +x (east), counter-clockwise positive, wrapped to (-pi, pi].
- Lane index 0 is the rightmost lane of its road.
- Lane coordinates: ``s`` is the arc length along the lane centre line, ``t`` the signed lateral
  offset from it (positive to the left).
- Lane offsets (``s``, mission and goal offsets, ``depart_pos``) are metres along the drawn lane.
  SUMO measures a lane by its ``length`` attribute, which netconvert may set apart from the shape
  (up to ~20% on real networks); positions handed to SUMO are scaled by ``lane_sumo_length /
  lane_length`` (:meth:`RoadMap.to_sumo_pos`), so an offset means the same place to both.

Variable-length per-lane data is stored CSR-style: ``X_offsets[i]:X_offsets[i + 1]`` slices the
flat array ``X`` for lane ``i``.
"""

from __future__ import annotations

import hashlib
import io
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from smarts.cache import atomic_write_bytes
from smarts.maps.errors import MapError
from smarts.records import picklable_state

MARK_CROSSWALK, MARK_BIKE_LANE, MARK_SPEED_BUMP = 1, 2, 3
"""Kinds of :attr:`RoadMap.mark_kind`: a pedestrian crossing, a bike lane (not driven by cars), a
speed bump."""
OPTIONAL_FIELDS = ("mark_kind", "mark_offsets", "mark_points")
"""Fields a saved map may lack (written before they existed): they take their empty defaults."""

CHECKSUM_KEY = "_sha256"
"""Entry of a saved map holding the SHA-256 of all its other arrays (see :func:`arrays_sha256`)."""


def arrays_sha256(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over the names, dtypes, shapes and bytes of ``arrays`` (in name order)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        value = np.ascontiguousarray(arrays[name])
        h.update(f"{name}\0{value.dtype.str}\0{value.shape}\0".encode())
        h.update(value.tobytes())
    return h.hexdigest()


@dataclass
class RoadMap:
    """Arrays describing lanes, their topology, a segment index and a drivable-area raster."""

    source: str
    """Path of the file the map was compiled from."""
    content_hash: str
    """SHA-256 of the source file's bytes (the cache key)."""

    # --- lanes (L of them) ---
    lane_ids: list[str]
    road_ids: list[str]
    lane_road: np.ndarray  # int32[L] index into road_ids
    lane_index: np.ndarray  # int16[L] 0 = rightmost on its road
    lane_width: np.ndarray  # float64[L]
    lane_speed_limit: np.ndarray  # float64[L] m/s
    lane_length: np.ndarray  # float64[L] arc length of the centre polyline
    lane_sumo_length: np.ndarray  # float64[L] SUMO's lane length (its ``length`` attribute)
    lane_internal: np.ndarray  # bool[L] lane lies inside a junction
    lane_left: np.ndarray  # int32[L] neighbour lane to the left on the same road, -1 if none
    lane_right: np.ndarray  # int32[L] neighbour lane to the right, -1 if none

    # centre polylines, CSR over lanes
    lane_point_offsets: np.ndarray  # int64[L + 1]
    points: np.ndarray  # float64[P, 2]
    point_s: np.ndarray  # float64[P] arc length of each point within its lane

    # topology through junctions (normal lane -> internal lane(s) -> normal lane), CSR over lanes
    succ_offsets: np.ndarray  # int64[L + 1]
    succ: np.ndarray  # int32[E]
    pred_offsets: np.ndarray  # int64[L + 1]
    pred: np.ndarray  # int32[E]

    # segments of all centre polylines (S of them) for projection
    seg_start: np.ndarray  # float64[S, 2]
    seg_vec: np.ndarray  # float64[S, 2] end - start
    seg_len: np.ndarray  # float64[S]
    seg_heading: np.ndarray  # float64[S]
    seg_lane: np.ndarray  # int32[S]
    seg_s0: np.ndarray  # float64[S] arc length at the segment start within its lane

    # uniform grid over segments: cell (ix, iy) lists segments within ``grid_margin`` of the cell
    grid_origin: np.ndarray  # float64[2]
    grid_cell: float
    grid_shape: tuple[int, int]  # (nx, ny)
    grid_margin: float
    grid_offsets: np.ndarray  # int64[nx * ny + 1], cell id = ix * ny + iy
    grid_segs: np.ndarray  # int32[...]

    # drivable-area raster: raster[iy, ix] is True where the road surface is
    raster_origin: np.ndarray  # float64[2] map position of the corner of cell (0, 0)
    raster_resolution: float  # metres per cell
    drivable: np.ndarray  # bool[H, W]

    # lane points resampled at ~1 m spacing for waypoints, CSR over lanes
    lanepoint_offsets: np.ndarray  # int64[L + 1]
    lanepoints: np.ndarray  # float64[Q, 2]
    lanepoint_s: np.ndarray  # float64[Q]
    lanepoint_heading: np.ndarray  # float64[Q]

    bounds: np.ndarray  # float64[4] xmin, ymin, xmax, ymax

    junction_shapes: list[np.ndarray] = field(default_factory=list)
    """Junction outlines (float64[k, 2]) drawn into the drivable raster and the renderer."""

    # --- connections through junctions (C of them), for right of way and traffic signals ---
    conn_from: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # incoming lane
    conn_via: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # internal lane or -1
    conn_to: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # outgoing lane
    conn_tls: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # signal index or -1
    conn_link: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # link index in it
    conn_major: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # has right of way
    conn_dir: np.ndarray = field(default_factory=lambda: np.zeros(0, "<U1"))  # s l r t L R (SUMO)

    # --- traffic signals (T of them) and their fixed-time programs, phases CSR over signals ---
    tls_ids: list[str] = field(default_factory=list)
    tls_offset: np.ndarray = field(default_factory=lambda: np.zeros(0))  # s, program time at t=0
    tls_phase_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    tls_phase_duration: np.ndarray = field(default_factory=lambda: np.zeros(0))  # s
    tls_phase_state: np.ndarray = field(default_factory=lambda: np.zeros(0, "<U1"))
    """One SUMO state string per phase (a char per link index: r, y, g/G, o, ...)."""

    # --- stop signs (N of them; from dataset maps such as Waymo's) ---
    stop_sign_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # float64[N, 2] position
    stop_sign_lane: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))  # lane it controls, -1 if none

    # --- marks on or beside the road (K of them; from dataset maps), polygons CSR over marks ---
    mark_kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))  # MARK_* below
    mark_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))  # int64[K + 1]
    mark_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # float64[P, 2] outlines

    lane_index_of: dict[str, int] = field(default_factory=dict, repr=False)
    road_index_of: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.lane_index_of:
            self.lane_index_of = {lane: i for i, lane in enumerate(self.lane_ids)}
        if not self.road_index_of:
            self.road_index_of = {road: i for i, road in enumerate(self.road_ids)}

    # ------------------------------------------------------------------ accessors
    @property
    def num_lanes(self) -> int:
        return len(self.lane_ids)

    def lane(self, lane_id: str) -> int:
        """Index of a lane by its id, with an error that names the id when it is unknown."""
        try:
            return self.lane_index_of[lane_id]
        except KeyError:
            raise KeyError(f"map {self.source!r} has no lane {lane_id!r}") from None

    def road(self, road_id: str) -> int:
        try:
            return self.road_index_of[road_id]
        except KeyError:
            raise KeyError(f"map {self.source!r} has no road {road_id!r}") from None

    def __getstate__(self) -> dict:
        # Kernel records cached on the map (``smarts.core.sim_records.lanes_record``) are numba
        # objects that do not pickle; the process that loads the map makes them at first use.
        return picklable_state(self.__dict__)

    def own_lanes(self) -> range:
        """Indices of this map's own lanes: all of them, except in a window of a stack of maps
        (``smarts.maps.stack``), where the arrays hold every map's lanes."""
        return self.__dict__.get("_own_lanes") or range(self.num_lanes)

    def own_roads(self) -> range:
        """Indices of this map's own roads (see :meth:`own_lanes`)."""
        return self.__dict__.get("_own_roads") or range(len(self.road_ids))

    def road_lanes(self, road: int) -> np.ndarray:
        """Lane indices of a road, rightmost first."""
        lanes = np.flatnonzero(self.lane_road == road)
        return lanes[np.argsort(self.lane_index[lanes], kind="stable")]

    def successors(self, lane: int) -> np.ndarray:
        return self.succ[self.succ_offsets[lane] : self.succ_offsets[lane + 1]]

    def predecessors(self, lane: int) -> np.ndarray:
        return self.pred[self.pred_offsets[lane] : self.pred_offsets[lane + 1]]

    def to_sumo_pos(self, lane: int, s: float) -> float:
        """SUMO's position on ``lane`` for arc length ``s`` along its shape (clamped to the lane):
        SUMO counts positions against the lane's ``length`` attribute, which may differ from the
        shape's length."""
        geometric, sumo = float(self.lane_length[lane]), float(self.lane_sumo_length[lane])
        scale = sumo / geometric if geometric > 0 else 1.0
        return min(max(float(s) * scale, 0.0), sumo)

    def from_sumo_pos(self, lane: int, pos: float) -> float:
        """Arc length along ``lane``'s shape for SUMO's position ``pos`` (inverse of
        :meth:`to_sumo_pos`)."""
        geometric, sumo = float(self.lane_length[lane]), float(self.lane_sumo_length[lane])
        scale = geometric / sumo if sumo > 0 else 1.0
        return min(max(float(pos) * scale, 0.0), geometric)

    def lane_polyline(self, lane: int) -> np.ndarray:
        return self.points[self.lane_point_offsets[lane] : self.lane_point_offsets[lane + 1]]

    def marks(self, kind: int | None = None) -> list[np.ndarray]:
        """Outlines (float64[k, 2]) of the marks of ``kind`` (None: every mark)."""
        off = self.mark_offsets
        return [self.mark_points[off[i] : off[i + 1]] for i in range(len(self.mark_kind))
                if kind is None or int(self.mark_kind[i]) == kind]  # fmt: skip

    def lane_lanepoints(self, lane: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xy[n, 2], s[n], heading[n]) of a lane's ~1 m lanepoints."""
        a, b = self.lanepoint_offsets[lane], self.lanepoint_offsets[lane + 1]
        return self.lanepoints[a:b], self.lanepoint_s[a:b], self.lanepoint_heading[a:b]

    # ------------------------------------------------------------------ persistence
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every field as plain arrays (strings as unicode arrays, no objects)."""
        arrays: dict[str, np.ndarray] = {}
        for f in fields(self):
            if f.name in ("lane_index_of", "road_index_of"):
                continue
            value = getattr(self, f.name)
            if f.name == "junction_shapes":
                lengths = np.array([len(s) for s in value], dtype=np.int64)
                arrays["junction_shape_offsets"] = np.concatenate([[0], np.cumsum(lengths)])
                arrays["junction_shape_points"] = np.concatenate(value) if value else np.zeros((0, 2))
                continue
            if isinstance(value, list):
                value = np.array(value, dtype=np.str_)
            arrays[f.name] = np.asarray(value)
        return arrays

    @classmethod
    def from_arrays(cls, data: Mapping[str, np.ndarray]) -> "RoadMap":
        kwargs = {}
        for f in fields(cls):
            if f.name in ("lane_index_of", "road_index_of", "junction_shapes"):
                continue
            if f.name in OPTIONAL_FIELDS and f.name not in data:
                continue
            value = data[f.name]
            if f.name in ("lane_ids", "road_ids", "tls_ids"):
                value = [str(v) for v in value]
            elif f.name in ("source", "content_hash"):
                value = str(value)
            elif f.name in ("grid_cell", "grid_margin", "raster_resolution"):
                value = float(value)
            elif f.name == "grid_shape":
                value = (int(value[0]), int(value[1]))
            kwargs[f.name] = value
        offsets = data["junction_shape_offsets"]
        pts = data["junction_shape_points"]
        kwargs["junction_shapes"] = [pts[offsets[i] : offsets[i + 1]] for i in range(len(offsets) - 1)]
        return cls(**kwargs)

    def save(self, path: Path) -> None:
        """Write every field to one ``.npz`` file (no pickles, so loading runs no code).

        The file records the SHA-256 of its arrays, checked by :meth:`load`, and is written
        atomically: readers see the old file, no file, or the whole new one.
        """
        arrays = self.to_arrays()
        arrays[CHECKSUM_KEY] = np.array(arrays_sha256(arrays))
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        atomic_write_bytes(Path(path), buffer.getvalue())

    @classmethod
    def load(cls, path: Path) -> "RoadMap":
        """Read a file written by :meth:`save`; a :class:`MapError` when it is unreadable, partial
        or does not match its recorded SHA-256."""
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
        except Exception as err:  # zip, npy and OS errors alike: the file is unusable
            raise MapError(f"{path}: unreadable compiled map ({type(err).__name__}: {err})") from None
        recorded = arrays.pop(CHECKSUM_KEY, None)
        if recorded is None:
            raise MapError(f"{path}: compiled map without a recorded checksum")
        if str(recorded) != arrays_sha256(arrays):
            raise MapError(f"{path}: compiled map does not match its recorded SHA-256")
        try:
            return cls.from_arrays(arrays)
        except (KeyError, IndexError, TypeError, ValueError) as err:
            raise MapError(f"{path}: compiled map is missing or has a malformed field ({err})") from None
