"""A recorded dataset's tracks as flat arrays: one contiguous run of frames per road user.

Every reader (NGSIM, Argoverse 2, Waymo) produces a :class:`Recording`. Tracks are stored CSR-style
(``offsets[v]:offsets[v + 1]`` slices road user ``v``'s frames out of the flat state arrays), so a
recording of thousands of vehicles over an hour costs memory for its samples only, and the replay
provider gathers every road user's state at a time with one vectorised lookup.

Frames are the recording's own clock: frame ``k`` is at ``times[k - start_frame]`` seconds after the
first frame (Waymo's jittery timestamps as recorded), or at ``(k - start_frame) * dt`` when the source
has a fixed rate (NGSIM, Argoverse 2). A simulation time maps to a (fractional) frame through
:meth:`Recording.frame_of`, which snaps to a recorded frame within :data:`TIME_TOLERANCE` of a frame
interval, so the first and last frames are always hit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.geometry import wrap_angle
from smarts.core.spec.replay import MAX_COORDINATE  # noqa: F401 - the readers' bound, kept importable here
from smarts.core.vehicle_table import VehicleType


class ObjectKind(IntEnum):
    """What a recorded road user is, as the dataset says (wider than the vehicle table's types)."""

    PASSENGER = 0
    BUS = 1
    TRUCK = 2
    MOTORCYCLE = 3
    PEDESTRIAN = 4
    CYCLIST = 5


def table_type(kind: int) -> VehicleType:
    """The vehicle table's type for an object kind. A cyclist is a motorcycle-sized two-wheeler to
    the table until the table has a bicycle type of its own."""
    if kind == ObjectKind.CYCLIST:
        return getattr(VehicleType, "BICYCLE", VehicleType.MOTORCYCLE)
    return VehicleType(int(kind))


DRIVABLE_KINDS = (ObjectKind.PASSENGER, ObjectKind.BUS, ObjectKind.TRUCK, ObjectKind.MOTORCYCLE)
"""Kinds an agent may take over (a pedestrian or cyclist is not driven by a vehicle model)."""

# kinds of DatasetMap.marks
CROSSWALK, BIKE_LANE, SPEED_BUMP = 1, 2, 3
MARK_NAMES = {CROSSWALK: "crosswalk", BIKE_LANE: "bike_lane", SPEED_BUMP: "speed_bump"}
# kinds of DatasetMap.lines
LINE_KINDS = ("edge", "solid_white", "dashed_white", "solid_yellow", "dashed_yellow", "double_yellow", "other")

MAX_FRAMES = 10_000_000
"""Frames one recording may span (11.5 days at 10 Hz): the limit checked before any per-frame array
is allocated, so a file claiming a huge frame range is an error, not a memory exhaustion."""
MAX_GAP_SECONDS = 10.0
"""A track's missing frames are filled by interpolation up to this long a gap; a longer gap is two
road users sharing an id (or a broken file), refused with both frames named."""
MAX_SAMPLES = 50_000_000
"""Samples (after filling gaps) one recording may hold: about 2 GB of state arrays."""
MAX_SPEED = 200.0
"""m/s: no road user is faster; a larger speed is a broken value."""
MAX_SIZE = 100.0
"""m: no road user's box is longer or wider."""


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
    left: list[list[tuple[str, int, int, int, int]]]
    """Per lane, its left neighbours: (neighbour id, first and last point of this lane, first and
    last point of the neighbour) where the two run side by side and a lane change may happen."""
    right: list[list[tuple[str, int, int, int, int]]]
    outlines: list[np.ndarray] = field(default_factory=list)
    """Drivable-area polygons (float64[k, 2]) drawn into the drivable raster."""
    stop_signs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    stop_sign_lanes: list[str | None] = field(default_factory=list)
    """The first lane each stop sign controls (a lane id of ``lane_ids``), None when not given."""
    marks: list[np.ndarray] = field(default_factory=list)
    """Crosswalk, bike lane and speed bump polygons (float64[k, 2])."""
    mark_kinds: list[int] = field(default_factory=list)
    """``CROSSWALK``, ``BIKE_LANE`` or ``SPEED_BUMP`` per mark."""
    lines: list[np.ndarray] = field(default_factory=list)
    """Painted lines and road edges (float64[k, 2]) for pictures."""
    line_kinds: list[str] = field(default_factory=list)
    """One of :data:`LINE_KINDS` per line."""
    signal_lanes: list[str] = field(default_factory=list)
    """Lanes controlled by a recorded traffic signal (Waymo), in the order of
    ``Recording.signal_states``' columns."""
    signal_stops: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    """float64[S, 2]: where road users stop for each signal (NaN when the dataset gives none)."""


def full_span(n_self: int, other: str, n_other: int) -> tuple[str, int, int, int, int]:
    """A neighbour that runs alongside for both lanes' whole length (Argoverse 2's neighbours)."""
    return (other, 0, n_self - 1, 0, n_other - 1)


@dataclass
class Recording:
    """Tracks of ``V`` recorded road users on the recording's frame grid.

    ``first[v]`` is road user ``v``'s first frame and ``count[v]`` its number of consecutive
    frames; its samples are ``x[offsets[v]:offsets[v + 1]]`` (and the same for ``y``, ``heading``,
    ``speed``). Positions are metres in the map frame, headings radians (0 along +x,
    counter-clockwise), speeds m/s. ``dt`` is the nominal frame interval; ``times`` (when given)
    the recorded time of every frame from the first, which the clock follows instead.
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
    kind: np.ndarray | None = None
    """int8[V] :class:`ObjectKind`; None: the kinds of ``vtype``."""
    times: np.ndarray | None = None
    """float64[frames]: seconds of each frame after the first; None: ``k * dt``."""
    signal_states: np.ndarray | None = None
    """int8[frames, S]: Waymo's signal state codes (0 unknown .. 8) of ``road_map.signal_lanes``."""
    skipped: dict[str, str] = field(default_factory=dict)
    """Ids of recorded objects that are not replayed, and what they are (for messages)."""
    ego: str | None = None
    """The recording vehicle's id (Waymo's self-driving car, Argoverse 2's AV), when it is replayed."""
    offsets: np.ndarray = field(init=False)
    index_of: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        self.first = np.asarray(self.first, dtype=np.int64)
        self.count = np.asarray(self.count, dtype=np.int64)
        self.vtype = np.asarray(self.vtype, dtype=np.int8)
        if self.kind is None:
            self.kind = self.vtype.copy()
        self.kind = np.asarray(self.kind, dtype=np.int8)
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
        """int64[V]: each road user's last frame."""
        return self.first + self.count - 1

    @property
    def frames(self) -> int:
        """Frames from the first recorded one to the last (0 for an empty recording)."""
        if self.times is not None:
            return len(self.times)
        return int(self.last.max() - self.first.min() + 1) if self.ids else 0

    @property
    def start_frame(self) -> int:
        if self.times is not None:
            return 0
        return int(self.first.min()) if self.ids else 0

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        if self.times is not None:
            return float(self.times[-1]) if len(self.times) else 0.0
        return max(self.frames - 1, 0) * self.dt

    def extent(self) -> tuple[float, float, float, float]:
        """xmin, ymin, xmax, ymax of every recorded position."""
        if not self.ids:
            return (0.0, 0.0, 0.0, 0.0)
        return (float(self.x.min()), float(self.y.min()), float(self.x.max()), float(self.y.max()))

    # ------------------------------------------------------------------ the clock
    def time_of(self, frame: float) -> float:
        """Seconds after the first frame of (integer) frame ``frame``."""
        rel = int(round(frame)) - self.start_frame
        if self.times is None:
            return float(rel) * self.dt
        n = len(self.times)
        if rel < 0:
            return float(self.times[0] + rel * self.dt)
        if rel >= n:
            return float(self.times[-1] + (rel - n + 1) * self.dt)
        return float(self.times[rel])

    def frame_of(self, time: float) -> float:
        """The (fractional) frame at ``time`` seconds after the first frame: on a recorded frame when
        within :data:`TIME_TOLERANCE` frame intervals of it, linear between frames, and one
        nominal interval per frame before the first and after the last."""
        if self.times is None:
            return self.start_frame + time / self.dt
        times = self.times
        n = len(times)
        if n == 0:
            return float(self.start_frame)
        k = int(np.searchsorted(times, time, side="right")) - 1  # times[k] <= time < times[k + 1]
        tol = TIME_TOLERANCE * self.dt
        for j in (k, k + 1):
            if 0 <= j < n and abs(time - times[j]) <= tol:
                return float(self.start_frame + j)
        if k < 0:
            return self.start_frame + (time - times[0]) / self.dt
        if k >= n - 1:
            return self.start_frame + n - 1 + (time - times[-1]) / self.dt
        return self.start_frame + k + (time - times[k]) / (times[k + 1] - times[k])

    def entry_time(self, vehicle: int) -> float:
        """Seconds from the recording's first frame to this road user's first."""
        return self.time_of(int(self.first[vehicle]))

    def exit_time(self, vehicle: int) -> float:
        return self.time_of(int(self.last[vehicle]))

    def track(self, vehicle: int) -> np.ndarray:
        """float64[count, 4]: x, y, heading, speed of one road user at its frames."""
        a, b = self.offsets[vehicle], self.offsets[vehicle + 1]
        return np.stack([self.x[a:b], self.y[a:b], self.heading[a:b], self.speed[a:b]], axis=1)

    def kind_name(self, vehicle: int) -> str:
        return ObjectKind(int(self.kind[vehicle])).name.lower()

    # ------------------------------------------------------------------ selection
    def select(self, keep: np.ndarray) -> Recording:
        """The recording with only the road users where ``keep`` (bool[V]) holds."""
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
            kind=self.kind[keep],
            times=self.times,
            signal_states=self.signal_states,
            skipped=dict(self.skipped),
            ego=self.ego
            if self.ego is not None and self.ego in self.index_of and keep[self.index_of[self.ego]]
            else None,
        )

    # ------------------------------------------------------------------ state at a time
    def state_at(self, frame_pos: float, vehicles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which road users are recorded at fractional frame ``frame_pos`` and their interpolated
        state: (bool[n] present, float64[4, n] x, y, heading, speed; NaN where absent).

        ``vehicles`` (int64 indices) restricts the lookup; None: every road user. Linear in
        position and speed, along the shorter arc in heading; exact at recorded frames."""
        idx = np.arange(self.num_vehicles) if vehicles is None else np.asarray(vehicles, dtype=np.int64)
        return interpolate(
            frame_pos, self.first[idx], self.count[idx], self.offsets[idx], self.x, self.y, self.heading, self.speed
        )

    def signals_at(self, frame_pos: float) -> np.ndarray | None:
        """int8[S]: the signal states at the recorded frame at or before ``frame_pos`` (None when
        the recording has no signals)."""
        if self.signal_states is None or self.signal_states.shape[1] == 0:
            return None
        rel = int(np.floor(frame_pos - self.start_frame + FRAME_EPS))
        rel = min(max(rel, 0), len(self.signal_states) - 1)
        return self.signal_states[rel]


FRAME_EPS = 1e-6
"""Fraction of a frame by which a time may miss a recorded frame and still count as on it."""
TIME_TOLERANCE = 0.1
"""Fraction of the nominal frame interval within which a time counts as a recorded frame's time
(Waymo's timestamps jitter by a few tenths of a millisecond around 0.1 s)."""


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


def check_values(
    source: str, column: str, values: np.ndarray, *, where: str = "data row", bound: float | None = None,
    positive: bool = False, rows: np.ndarray | None = None,
) -> None:  # fmt: skip
    """Every value of a numeric column finite (and within ``bound`` in magnitude, and positive when
    asked); else a ``ReplayError`` naming the file, the column and the first bad row (1-based, or
    ``rows[i]`` when given)."""
    values = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(values)
    if bound is not None:
        bad |= np.abs(values) > bound
    if positive:
        bad |= ~(values > 0)
    if not bad.any():
        return
    i = int(np.flatnonzero(bad)[0])
    row = int(rows[i]) if rows is not None else i + 1
    value = float(values[i])
    if not np.isfinite(value):
        expected = "a finite number"
    elif positive and not value > 0:
        expected = "a positive size"
    else:
        expected = f"a value within +-{bound:g}"
    raise ReplayError(f"{source}: column {column}: expected {expected}, got {value:g} in {where} {row}")


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
    kind: np.ndarray | None = None,
    times: np.ndarray | None = None,
    signal_states: np.ndarray | None = None,
    skipped: dict[str, str] | None = None,
) -> Recording:
    """Group per-sample rows (any order) into tracks.

    Frames a road user skips are filled by linear interpolation so each track is one run (gaps
    longer than :data:`MAX_GAP_SECONDS` and recordings beyond :data:`MAX_FRAMES` or
    :data:`MAX_SAMPLES` are refused before anything is allocated). Heading and speed, when not given
    (``None``), come from the positions (:func:`kinematics_from_positions`); the positions themselves
    are kept as recorded. Per-road-user ``length``/``width``/``vtype``/``kind`` are taken from its
    first sample.
    """
    order, vids, frames, starts, ends = _sorted_tracks(source, vehicle_ids, frames)
    _check_extent(source, vids, frames, starts, ends, dt)
    x, y = np.asarray(x, np.float64)[order], np.asarray(y, np.float64)[order]
    heading = None if heading is None else np.asarray(heading, np.float64)[order]
    speed = None if speed is None else np.asarray(speed, np.float64)[order]
    length, width = np.asarray(length, np.float64)[order], np.asarray(width, np.float64)[order]
    vtype = np.asarray(vtype, np.int8)[order]
    kind = vtype if kind is None else np.asarray(kind, np.int8)[order]
    ids = vids[starts].tolist()
    first = frames[starts]
    count = frames[ends - 1] - first + 1
    fill = _gap_filler(frames, starts, ends, first, count)
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
        kind=kind[starts],
        times=times,
        signal_states=signal_states,
        skipped=dict(skipped or {}),
    )


def _sorted_tracks(source: str, vehicle_ids: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, ...]:
    """Samples sorted by (road user, frame): the sort order, sorted ids and frames, and each track's
    [start, end) in them; two samples of one road user at one frame are an error."""
    vehicle_ids = np.asarray(vehicle_ids).astype(str)
    frames = np.asarray(frames, dtype=np.int64)
    if len(vehicle_ids) == 0:
        raise ReplayError(f"{source}: no vehicle samples")
    order = np.lexsort((frames, vehicle_ids))
    vids, frames = vehicle_ids[order], frames[order]
    dup = (vids[1:] == vids[:-1]) & (frames[1:] == frames[:-1])
    if dup.any():
        i = int(np.flatnonzero(dup)[0])
        raise ReplayError(f"{source}: vehicle {str(vids[i])!r} has two samples at frame {int(frames[i])}")
    starts = np.flatnonzero(np.r_[True, vids[1:] != vids[:-1]])
    ends = np.r_[starts[1:], len(vids)]
    return order, vids, frames, starts, ends


def _gap_filler(
    frames: np.ndarray, starts: np.ndarray, ends: np.ndarray, first: np.ndarray, count: np.ndarray
) -> Callable[..., np.ndarray]:
    """A function that lays one sorted sample column onto every track's full run of frames,
    interpolating the frames a road user skips (angles unwrapped first, wrapped after)."""
    total = int(count.sum())
    # every road user's frames on its own full run: position of each sample in the output
    out_off = np.concatenate([[0], np.cumsum(count)])
    dest = out_off[np.repeat(np.arange(len(starts)), ends - starts)] + (frames - np.repeat(first, ends - starts))
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

    return fill


def _check_extent(source: str, vids: np.ndarray, frames: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                  dt: float) -> None:  # fmt: skip
    """Refuse frame ranges that would need huge arrays, before they are allocated."""
    gap = np.diff(frames)
    gap[starts[1:] - 1] = 1  # across two tracks is no gap
    max_gap = max(int(round(MAX_GAP_SECONDS / dt)), 1)
    if gap.size and gap.max() > max_gap:
        i = int(np.argmax(gap))
        raise ReplayError(
            f"{source}: vehicle {str(vids[i])!r} has no samples from frame {int(frames[i])} to frame "
            f"{int(frames[i + 1])} (a gap of {(int(gap[i]) - 1) * dt:g} s); gaps of up to {MAX_GAP_SECONDS:g} s are "
            "filled by interpolation: a longer one is two road users with one id, or a broken frame number"
        )
    span = int(frames.max()) - int(frames.min()) + 1
    if span > MAX_FRAMES:
        lo, hi = int(frames.min()), int(frames.max())
        raise ReplayError(f"{source}: frames run from {lo} to {hi} ({span} frames); at most {MAX_FRAMES} are "
                          "supported (a broken frame number?)")  # fmt: skip
    total = int((frames[ends - 1] - frames[starts] + 1).sum())
    if total > MAX_SAMPLES:
        raise ReplayError(f"{source}: the tracks hold {total} frames in all; at most {MAX_SAMPLES} are supported")


HEADING_ERROR = np.radians(2.0)
"""rad: the heading error (one standard deviation) a chord may have from position noise; sets the
chord length used for headings from positions (:func:`heading_baseline`)."""
MIN_BASELINE = 0.5
"""m: the shortest chord a heading is taken from (noise-free data still needs a displacement)."""
MAX_BASELINE = 5.0
"""m: the longest (very noisy data would otherwise hold headings through turns)."""
HOLD_SECONDS = 10.0
"""s: how far along a track a chord end is looked for; a road user that moves less than the chord
in that time is standing: its heading is held."""


def heading_baseline(x: np.ndarray, y: np.ndarray, count: np.ndarray, smooth_frames: int) -> float:
    """The chord length (m) over which a heading from noisy positions is within
    :data:`HEADING_ERROR`: the file's frame-to-frame position jitter ``s`` is estimated from second
    differences of positions (robustly: 1.4826 x their median absolute value, over sqrt(6), since a
    second difference of white noise has six times its variance and driving itself adds only
    centimetres at 10 Hz), the smoothing over ``smooth_frames`` frames divides it by
    sqrt(smooth_frames), and a chord between two such points has a direction error of about
    sqrt(2) s / L radians."""
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    i = np.arange(1, x.size - 1)
    inside = np.ones(x.size, dtype=bool)
    inside[start] = False
    inside[np.minimum(start + count - 1, x.size - 1)] = False
    i = i[inside[i]]
    if i.size < 10:
        return MIN_BASELINE
    d2 = np.concatenate([x[i + 1] - 2 * x[i] + x[i - 1], y[i + 1] - 2 * y[i] + y[i - 1]])
    jitter = 1.4826 * float(np.median(np.abs(d2))) / np.sqrt(6.0)
    smoothed = jitter / np.sqrt(max(int(smooth_frames), 1))
    return float(np.clip(np.sqrt(2.0) * smoothed / HEADING_ERROR, MIN_BASELINE, MAX_BASELINE))


def kinematics_from_positions(
    x: np.ndarray, y: np.ndarray, count: np.ndarray, dt: float, smooth_frames: int, baseline: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Heading and speed of concatenated tracks from their positions.

    Positions are smoothed by a centred moving average over ``smooth_frames`` frames (narrower at
    a track's ends); the speed is their central difference (one-sided at a track's ends). The
    heading at a frame is the direction of the chord between the nearest earlier and later smoothed
    positions at least half ``baseline`` metres away (from :func:`heading_baseline`; the frame itself
    on a side where there is none), so it is defined by a displacement larger than the noise
    however slowly the road user moves. Where the road user moves less than half the baseline in
    :data:`HOLD_SECONDS` either way, it stands: the heading is held from when it last moved (its
    first moving heading before that)."""
    from smarts.replay.kinematics import chord_headings

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
    speed = np.hypot(sx[nxt] - sx[prev], sy[nxt] - sy[prev]) / span
    if baseline is None:
        baseline = heading_baseline(x, y, count, smooth_frames)
    window = max(int(round(HOLD_SECONDS / dt)), 1)
    heading, defined = chord_headings(sx, sy, start, end, 0.5 * baseline, window)
    # carry the last defined heading forward within each track, then the first one backward
    carry = _carry_forward(np.where(defined, i, -1), start)
    back = _carry_backward(np.where(defined, i, n), end)
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
