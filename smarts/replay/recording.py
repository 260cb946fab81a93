"""A recorded dataset's tracks as flat arrays: one contiguous run of frames per vehicle.

Every reader (NGSIM, Argoverse 2, Waymo) produces a :class:`Recording`. Tracks are stored CSR-style
(``offsets[v]:offsets[v + 1]`` slices vehicle ``v``'s frames out of the flat state arrays), so a
recording of thousands of vehicles over an hour costs memory for its samples only, and the replay
provider gathers every vehicle's state at a time with one vectorised lookup.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.geometry import wrap_angle


@dataclass
class DatasetMap:
    """A dataset's own lane graph (Argoverse 2 map JSON, Waymo map features), ready for
    ``smarts.replay.lane_map.compile_lane_map``."""

    source: str
    lane_ids: list[str]
    polylines: list[np.ndarray]  # float64[n, 2] centre lines, in driving direction
    widths: np.ndarray  # float64[L]
    speed_limits: np.ndarray  # float64[L] m/s
    internal: np.ndarray  # bool[L] lanes inside an intersection
    successors: list[list[str]]
    left: list[str | None]
    right: list[str | None]
    outlines: list[np.ndarray] = field(default_factory=list)
    """Drivable-area polygons (float64[k, 2]) drawn into the drivable raster."""
    stop_signs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    stop_sign_lanes: list[str | None] = field(default_factory=list)
    """The first lane each stop sign controls (a lane id of ``lane_ids``), None when not given."""


@dataclass
class Recording:
    """Tracks of ``V`` recorded vehicles on a uniform frame grid (frame ``k`` at ``k * dt`` s).

    ``first[v]`` is vehicle ``v``'s first frame and ``count[v]`` its number of consecutive frames;
    its samples are ``x[offsets[v]:offsets[v + 1]]`` (and the same for ``y``, ``heading``,
    ``speed``). Positions are metres in the map frame, headings radians (0 along +x,
    counter-clockwise), speeds m/s.
    """

    source: str
    format: str
    ids: list[str]
    dt: float
    first: np.ndarray  # int64[V]
    count: np.ndarray  # int64[V]
    x: np.ndarray  # float64[N]
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    length: np.ndarray  # float64[V]
    width: np.ndarray  # float64[V]
    vtype: np.ndarray  # int8[V] smarts.core.vehicle_table.VehicleType
    road_map: DatasetMap | None = None
    offsets: np.ndarray = field(init=False)
    index_of: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        self.first = np.asarray(self.first, dtype=np.int64)
        self.count = np.asarray(self.count, dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(self.count)]).astype(np.int64)
        self.index_of = {vid: i for i, vid in enumerate(self.ids)}
        if len(self.index_of) != len(self.ids):
            raise ReplayError(f"{self.source}: vehicle ids are not unique")

    # ------------------------------------------------------------------ summary
    @property
    def num_vehicles(self) -> int:
        return len(self.ids)

    @property
    def last(self) -> np.ndarray:
        """int64[V]: each vehicle's last frame."""
        return self.first + self.count - 1

    @property
    def frames(self) -> int:
        """Frames from the first recorded one to the last (0 for an empty recording)."""
        return int(self.last.max() - self.first.min() + 1) if self.ids else 0

    @property
    def start_frame(self) -> int:
        return int(self.first.min()) if self.ids else 0

    @property
    def duration(self) -> float:
        return max(self.frames - 1, 0) * self.dt

    def extent(self) -> tuple[float, float, float, float]:
        """xmin, ymin, xmax, ymax of every recorded position."""
        if not self.ids:
            return (0.0, 0.0, 0.0, 0.0)
        return (float(self.x.min()), float(self.y.min()), float(self.x.max()), float(self.y.max()))

    def entry_time(self, vehicle: int) -> float:
        """Seconds from the recording's first frame to this vehicle's first."""
        return float(self.first[vehicle] - self.start_frame) * self.dt

    def exit_time(self, vehicle: int) -> float:
        return float(self.last[vehicle] - self.start_frame) * self.dt

    def track(self, vehicle: int) -> np.ndarray:
        """float64[count, 4]: x, y, heading, speed of one vehicle at its frames."""
        a, b = self.offsets[vehicle], self.offsets[vehicle + 1]
        return np.stack([self.x[a:b], self.y[a:b], self.heading[a:b], self.speed[a:b]], axis=1)

    # ------------------------------------------------------------------ selection
    def select(self, keep: np.ndarray) -> Recording:
        """The recording with only the vehicles where ``keep`` (bool[V]) holds."""
        keep = np.asarray(keep, dtype=bool)
        samples = np.repeat(keep, self.count)
        return Recording(
            source=self.source,
            format=self.format,
            ids=[vid for vid, k in zip(self.ids, keep.tolist()) if k],
            dt=self.dt,
            first=self.first[keep],
            count=self.count[keep],
            x=self.x[samples],
            y=self.y[samples],
            heading=self.heading[samples],
            speed=self.speed[samples],
            length=self.length[keep],
            width=self.width[keep],
            vtype=self.vtype[keep],
            road_map=self.road_map,
        )

    # ------------------------------------------------------------------ state at a time
    def state_at(self, frame_pos: float, vehicles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which vehicles are recorded at fractional frame ``frame_pos`` and their interpolated
        state: (bool[n] present, float64[4, n] x, y, heading, speed; NaN where absent).

        ``vehicles`` (int64 indices) restricts the lookup; None: every vehicle. Linear in position
        and speed, along the shorter arc in heading; exact at recorded frames."""
        idx = np.arange(self.num_vehicles) if vehicles is None else np.asarray(vehicles, dtype=np.int64)
        return interpolate(
            frame_pos, self.first[idx], self.count[idx], self.offsets[idx], self.x, self.y, self.heading, self.speed
        )


FRAME_EPS = 1e-6
"""Fraction of a frame by which a time may miss a recorded frame and still count as on it."""


def interpolate(
    frame_pos: float,
    first: np.ndarray,
    count: np.ndarray,
    offsets: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray,
    speed: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised state lookup of tracks (first frame, count, offset) at a fractional frame."""
    rel = frame_pos - first
    present = (rel >= -FRAME_EPS) & (rel <= count - 1 + FRAME_EPS)
    rel = np.clip(rel, 0.0, np.maximum(count - 1, 0))
    k0 = np.floor(rel + FRAME_EPS).astype(np.int64)
    k0 = np.minimum(k0, np.maximum(count - 2, 0))
    a = np.clip(rel - k0, 0.0, 1.0)
    i0 = offsets + k0
    i1 = np.minimum(i0 + 1, offsets + count - 1)
    i0 = np.minimum(i0, offsets + np.maximum(count - 1, 0))
    n = len(first)
    out = np.full((4, n), np.nan)
    if n == 0 or x.size == 0:
        return present, out
    i0 = np.clip(i0, 0, x.size - 1)
    i1 = np.clip(i1, 0, x.size - 1)
    out[0] = x[i0] + (x[i1] - x[i0]) * a
    out[1] = y[i0] + (y[i1] - y[i0]) * a
    out[2] = wrap_angle(heading[i0] + wrap_angle(heading[i1] - heading[i0]) * a)
    out[3] = speed[i0] + (speed[i1] - speed[i0]) * a
    out[:, ~present] = np.nan
    return present, out


def from_samples(
    source: str,
    fmt: str,
    vehicle_ids: np.ndarray,
    frames: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray | None,
    speed: np.ndarray | None,
    length: np.ndarray,
    width: np.ndarray,
    vtype: np.ndarray,
    dt: float,
    *,
    smooth_frames: int = 0,
    road_map: DatasetMap | None = None,
) -> Recording:
    """Group per-sample rows (any order) into tracks.

    Frames a vehicle skips are filled by linear interpolation so each track is one run. Heading and
    speed, when not given (``None``), come from the positions, smoothed over ``smooth_frames``
    frames first (noisy sources such as NGSIM); the positions themselves are kept as recorded.
    Per-vehicle ``length``/``width``/``vtype`` are taken from each vehicle's first sample.
    """
    vehicle_ids = np.asarray(vehicle_ids).astype(str)
    frames = np.asarray(frames, dtype=np.int64)
    order = np.lexsort((frames, vehicle_ids))
    vids, frames = vehicle_ids[order], frames[order]
    x, y = np.asarray(x, np.float64)[order], np.asarray(y, np.float64)[order]
    heading = None if heading is None else np.asarray(heading, np.float64)[order]
    speed = None if speed is None else np.asarray(speed, np.float64)[order]
    length, width = np.asarray(length, np.float64)[order], np.asarray(width, np.float64)[order]
    vtype = np.asarray(vtype, np.int8)[order]
    if len(vids) == 0:
        raise ReplayError(f"{source}: no vehicle samples")
    dup = (vids[1:] == vids[:-1]) & (frames[1:] == frames[:-1])
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        raise ReplayError(f"{source}: vehicle {str(vids[i])!r} has two samples at frame {int(frames[i])}")
    starts = np.flatnonzero(np.r_[True, vids[1:] != vids[:-1]])
    ends = np.r_[starts[1:], len(vids)]
    ids = vids[starts].tolist()
    first = frames[starts]
    count = frames[ends - 1] - first + 1
    total = int(count.sum())
    # every vehicle's frames on its own full run: position of each sample in the output
    out_off = np.concatenate([[0], np.cumsum(count)])
    dest = out_off[np.repeat(np.arange(len(ids)), ends - starts)] + (frames - np.repeat(first, ends - starts))
    full = np.zeros(total, dtype=bool)
    full[dest] = True
    grid = np.arange(total, dtype=np.float64)

    def fill(values: np.ndarray, angle: bool = False) -> np.ndarray:
        out = np.empty(total)
        if full.all():
            out[dest] = values
            return out
        v = np.unwrap(values) if angle else values  # gaps only inside a track, so one unwrap is fine
        out[:] = np.interp(grid, dest.astype(np.float64), v)
        return wrap_angle(out) if angle else out

    fx, fy = fill(x), fill(y)
    if heading is None or speed is None:
        dh, ds = kinematics_from_positions(fx, fy, count, dt, smooth_frames)
        heading = dh if heading is None else fill(heading, angle=True)
        speed = ds if speed is None else fill(speed)
    else:
        heading, speed = fill(heading, angle=True), fill(speed)
    return Recording(
        source=source,
        format=fmt,
        ids=ids,
        dt=dt,
        first=first,
        count=count,
        x=fx,
        y=fy,
        heading=heading,
        speed=speed,
        length=length[starts],
        width=width[starts],
        vtype=vtype[starts],
        road_map=road_map,
    )


def kinematics_from_positions(
    x: np.ndarray, y: np.ndarray, count: np.ndarray, dt: float, smooth_frames: int
) -> tuple[np.ndarray, np.ndarray]:
    """Heading and speed of concatenated tracks from their (smoothed) positions.

    Positions are smoothed by a centred moving average over ``smooth_frames`` frames (narrower at
    a track's ends), then differentiated with central differences (one-sided at the ends). A
    vehicle standing still keeps the heading it last moved with (its first moving heading before
    that), since the direction of a zero displacement says nothing."""
    n = x.size
    start = np.repeat(np.concatenate([[0], np.cumsum(count)[:-1]]), count)
    end = start + np.repeat(count, count)  # exclusive
    i = np.arange(n)
    # symmetric windows, narrowed near a track's ends, so a steady drive is left exactly as it is
    half = np.minimum(np.minimum(max(int(smooth_frames) // 2, 0), i - start), end - 1 - i)
    lo, hi = i - half, i + half + 1
    cx, cy = np.concatenate([[0.0], np.cumsum(x)]), np.concatenate([[0.0], np.cumsum(y)])
    sx = (cx[hi] - cx[lo]) / (hi - lo)
    sy = (cy[hi] - cy[lo]) / (hi - lo)
    prev = np.maximum(i - 1, start)
    nxt = np.minimum(i + 1, end - 1)
    span = np.maximum(nxt - prev, 1) * dt
    vx, vy = (sx[nxt] - sx[prev]) / span, (sy[nxt] - sy[prev]) / span
    speed = np.hypot(vx, vy)
    moving = speed > 0.05
    heading = np.arctan2(vy, vx)
    # carry the last moving heading forward within each track, then the first one backward
    carry = _carry_forward(np.where(moving, i, -1), start)
    back = _carry_backward(np.where(moving, i, n), end)
    src = np.where(carry >= 0, carry, back)
    src = np.where((src >= 0) & (src < n), src, i)
    return heading[src], speed


def _carry_forward(idx: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Per element, the latest index >= 0 at or before it within its track (-1 if none)."""
    # earlier tracks' indices are all below this track's start, so they never count here
    out = np.maximum.accumulate(np.maximum(idx, start - 1))
    return np.where(out >= start, out, -1)


def _carry_backward(idx: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Per element, the earliest index < n at or after it within its track (n if none)."""
    n = idx.size
    out = np.minimum.accumulate(np.minimum(idx, end)[::-1])[::-1]
    return np.where(out < end, out, n)
