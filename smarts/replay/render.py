"""Top-down pictures of a recording: the road (surface, edges, painted lines, crosswalks, bike lanes,
stop signs and the recorded signal states), recorded vehicles as boxes, cyclists and pedestrians in
their own colours; one frame or many.

Used by ``smarts replay show`` to check a dataset lines up with its map before driving in it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from smarts.core.errors import ReplayError
from smarts.core.geometry import box_corners
from smarts.replay.recording import BIKE_LANE, CROSSWALK, SPEED_BUMP, DatasetMap, ObjectKind, Recording

BACKGROUND = (24, 26, 30)
SURFACE = (52, 55, 60)
LANE = (96, 100, 108)
EDGE = (200, 200, 200)
WHITE = (235, 235, 235)
YELLOW = (230, 190, 40)
VEHICLE = (80, 170, 255)
EGO = (90, 220, 120)
CYCLIST = (255, 150, 40)
PEDESTRIAN = (255, 105, 180)
CROSSWALK_FILL = (120, 122, 128)
BIKE_FILL = (40, 100, 60)
BUMP = (230, 140, 40)
STOP_SIGN = (220, 30, 30)
TEXT = (230, 230, 230)
SIGNAL_COLOURS = {0: (130, 130, 130), 1: (235, 40, 40), 2: (245, 200, 30), 3: (40, 220, 80)}
"""Fill of a signal by colour (no signal/unknown, red, yellow, green)."""
SIGNAL_COLOUR_OF_STATE = (0, 1, 2, 3, 1, 2, 3, 1, 2)
"""Waymo signal state code -> colour index of :data:`SIGNAL_COLOURS`."""
LINE_STYLES = {"edge": (EDGE, False), "solid_white": (WHITE, False), "dashed_white": (WHITE, True),
               "solid_yellow": (YELLOW, False), "dashed_yellow": (YELLOW, True), "double_yellow": (YELLOW, False),
               "other": (LANE, True)}  # fmt: skip
SIGNAL_INSET = 3.0
"""m into its lane from the stop point at which a signal is drawn."""
LABEL_BAND = 16
"""Pixels above the road for the time and counts."""
MAX_PIXELS = 16_000_000
"""Pixels of one picture at most (a tall recording is fitted into this, not drawn larger)."""


class Canvas:
    """World-to-pixel transform fitting ``extent`` (xmin, ymin, xmax, ymax) in ``width`` pixels."""

    def __init__(self, extent: tuple[float, float, float, float], width: int, margin: float = 5.0, top: int = 0):
        xmin, ymin, xmax, ymax = extent
        self.x0, self.y1 = xmin - margin, ymax + margin
        self.top = int(top)
        span_x = max(xmax - xmin + 2 * margin, 1.0)
        span_y = max(ymax - ymin + 2 * margin, 1.0)
        self.scale = width / span_x
        self.size = (int(width), max(int(round(span_y * self.scale)), 16) + self.top)
        tallest = min(4 * width, MAX_PIXELS // max(int(width), 1))
        if self.size[1] > tallest:  # a tall recording: fit the height instead
            self.scale = (tallest - self.top) / span_y
            self.size = (max(int(round(span_x * self.scale)), 16), tallest)

    def pixels(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([(xy[..., 0] - self.x0) * self.scale, (self.y1 - xy[..., 1]) * self.scale + self.top], axis=-1)


def lane_lines(road_map) -> list[np.ndarray]:
    """Centre polylines of a compiled ``RoadMap``."""
    off = road_map.lane_point_offsets
    return [road_map.points[off[i] : off[i + 1]] for i in range(len(off) - 1)]


def _side(line: np.ndarray, offset: float) -> np.ndarray:
    """A polyline moved sideways by ``offset`` metres (positive to the left)."""
    d = np.gradient(line, axis=0) if len(line) > 1 else np.array([[1.0, 0.0]])
    norm = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    return line + np.stack([-d[:, 1], d[:, 0]], axis=1) / norm[:, None] * offset


class Scene:
    """What is drawn under the road users: built once per picture or video."""

    def __init__(self, rec: Recording, road_map=None):
        self.surfaces: list[np.ndarray] = []
        self.lines: list[tuple[np.ndarray, tuple, bool]] = []
        self.centres: list[np.ndarray] = []
        self.marks: list[tuple[np.ndarray, int]] = []
        self.stop_signs = np.zeros((0, 2))
        self.signals = np.zeros((0, 2))
        if road_map is not None:
            self._from_road_map(road_map)
        elif rec.road_map is not None:
            self._from_dataset(rec.road_map)

    def _from_road_map(self, rm) -> None:
        """A compiled map: lane surfaces, each road's outer edges solid and lane dividers dashed."""
        for lane, line in enumerate(lane_lines(rm)):
            half = 0.5 * float(rm.lane_width[lane])
            self.surfaces.append(np.concatenate([_side(line, half), _side(line, -half)[::-1]]))
            self.centres.append(line)
            outer_left = rm.lane_left[lane] < 0
            divider = not outer_left and not rm.lane_internal[lane]
            self.lines.append((_side(line, half), EDGE if outer_left else WHITE, divider))
            if rm.lane_right[lane] < 0 and not rm.lane_internal[lane]:
                self.lines.append((_side(line, -half), EDGE, False))
        self.surfaces += [np.asarray(s) for s in rm.junction_shapes if len(s) >= 3]
        off = rm.mark_offsets
        self.marks = [(rm.mark_points[off[i] : off[i + 1]], int(rm.mark_kind[i])) for i in range(len(rm.mark_kind))]
        self.stop_signs = np.asarray(rm.stop_sign_xy).reshape(-1, 2)

    def _from_dataset(self, dm: DatasetMap) -> None:
        """A dataset's own map: drivable areas (or lane strips), its painted lines and edges, marks."""
        widths = [w if w > 0 else 3.7 for w in np.asarray(dm.widths, dtype=float)]
        if dm.outlines:
            self.surfaces = [np.asarray(o) for o in dm.outlines]
        else:
            self.surfaces = [np.concatenate([_side(np.asarray(line), w / 2), _side(np.asarray(line), -w / 2)[::-1]])
                             for line, w in zip(dm.polylines, widths)]  # fmt: skip
        self.centres = [np.asarray(line) for line in dm.polylines]
        for line, kind in zip(dm.lines, dm.line_kinds):
            colour, dashed = LINE_STYLES.get(kind, LINE_STYLES["other"])
            self.lines.append((np.asarray(line), colour, dashed))
        self.marks = list(zip(dm.marks, dm.mark_kinds))
        self.stop_signs = np.asarray(dm.stop_signs).reshape(-1, 2)
        if dm.signal_lanes:
            index = {lane: k for k, lane in enumerate(dm.lane_ids)}
            xy = np.asarray(dm.signal_stops, dtype=np.float64).reshape(-1, 2).copy()
            for s, lane in enumerate(dm.signal_lanes):
                if lane not in index:
                    continue
                line = np.asarray(dm.polylines[index[lane]])
                # drawn a little way into the lane it controls, so lanes sharing a stop line show apart
                stop = xy[s] if np.isfinite(xy[s]).all() else line[0]
                start = float(np.argmin(np.hypot(*(line - stop).T)))
                along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
                at = along[int(start)] + (SIGNAL_INSET if start < len(line) - 1 else -SIGNAL_INSET)
                xy[s] = [np.interp(at, along, line[:, 0]), np.interp(at, along, line[:, 1])]
            self.signals = _spread(xy, 2.6)

    def extent(self) -> tuple[float, float, float, float] | None:
        """xmin, ymin, xmax, ymax of what is drawn under the road users (None: nothing)."""
        shapes = [np.asarray(p).reshape(-1, 2) for p in [*self.surfaces, *self.centres] if len(p)]
        if not shapes:
            return None
        xy = np.concatenate(shapes)
        return (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max()))

    def draw(self, draw: ImageDraw.ImageDraw, canvas: Canvas) -> None:
        px = max(canvas.scale, 1e-9)
        for poly in self.surfaces:
            if len(poly) >= 3:
                draw.polygon([tuple(p) for p in canvas.pixels(poly)], fill=SURFACE)
        fills = {CROSSWALK: CROSSWALK_FILL, BIKE_LANE: BIKE_FILL}
        for poly, kind in self.marks:
            if len(poly) < 3:
                continue
            points = [tuple(p) for p in canvas.pixels(poly)]
            if kind == SPEED_BUMP:
                draw.polygon(points, outline=BUMP, width=max(int(0.3 * px), 1))
            else:
                draw.polygon(points, fill=fills.get(kind, CROSSWALK_FILL))
            if kind == CROSSWALK:  # zebra stripes across its long side
                self._stripes(draw, canvas, np.asarray(poly))
        for line in self.centres:
            if len(line) >= 2:
                draw.line([tuple(p) for p in canvas.pixels(line)], fill=LANE, width=1)
        width = max(int(round(0.15 * px)), 1)
        for line, colour, dashed in self.lines:
            if len(line) < 2:
                continue
            pixels = canvas.pixels(line)
            if dashed:
                for piece in _dashes(pixels, 3.0 * px, 6.0 * px):
                    draw.line([tuple(p) for p in piece], fill=colour, width=width)
            else:
                draw.line([tuple(p) for p in pixels], fill=colour, width=width)
        r = max(0.8 * px, 3.0)
        for x, y in canvas.pixels(self.stop_signs):
            draw.regular_polygon((float(x), float(y), r), 8, fill=STOP_SIGN, outline=WHITE)

    def draw_signals(self, draw: ImageDraw.ImageDraw, canvas: Canvas, states: np.ndarray | None) -> None:
        if states is None or not len(self.signals):
            return
        r = max(1.2 * canvas.scale, 4.0)
        for (x, y), code in zip(canvas.pixels(self.signals), states.tolist()):
            colour = SIGNAL_COLOURS[SIGNAL_COLOUR_OF_STATE[int(code)] if 0 <= code < 9 else 0]
            draw.ellipse([x - r, y - r, x + r, y + r], fill=colour, outline=(10, 10, 10))

    @staticmethod
    def _stripes(draw: ImageDraw.ImageDraw, canvas: Canvas, poly: np.ndarray) -> None:
        """Stripes every 1 m along a crosswalk's longest side, as wide as the polygon."""
        edges = np.diff(np.concatenate([poly, poly[:1]]), axis=0)
        k = int(np.argmax(np.hypot(edges[:, 0], edges[:, 1])))
        along = edges[k] / max(np.hypot(*edges[k]), 1e-9)
        across = np.array([-along[1], along[0]])
        centre = poly.mean(axis=0)
        rel = poly - centre
        a = rel @ along
        b = rel @ across
        for t in np.arange(a.min() + 0.25, a.max(), 1.0):
            ends = centre + np.outer([t, t], along) + np.outer([b.min(), b.max()], across)
            draw.line([tuple(p) for p in canvas.pixels(ends)], fill=WHITE, width=max(int(0.5 * canvas.scale), 1))


def _spread(xy: np.ndarray, gap: float) -> np.ndarray:
    """Points closer than ``gap`` to an earlier one moved aside (by ``gap`` per earlier neighbour,
    across the direction from the first), so every signal of a shared stop line shows."""
    out = xy.copy()
    for k in range(1, len(out)):
        if not np.isfinite(out[k]).all():
            continue
        near = [j for j in range(k) if np.isfinite(xy[j]).all() and np.hypot(*(xy[j] - xy[k])) < gap]
        if near:
            d = xy[k] - xy[near[0]]
            n = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-9) if np.hypot(*d) > 1e-6 else np.array([0.0, 1.0])
            out[k] = xy[near[0]] + n * gap * len(near)
    return out


def _dashes(pixels: np.ndarray, on: float, off: float) -> list[np.ndarray]:
    """A pixel polyline cut into dashes ``on`` pixels long with ``off`` pixel gaps."""
    seg = np.hypot(*np.diff(pixels, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    out = []
    start = 0.0
    while start < s[-1]:
        stop = min(start + on, s[-1])
        inside = (s > start) & (s < stop)
        xs = np.concatenate([[start], s[inside], [stop]])
        out.append(np.stack([np.interp(xs, s, pixels[:, 0]), np.interp(xs, s, pixels[:, 1])], axis=1))
        start = stop + off
    return out


def render_frame(
    rec: Recording, frame: float, canvas: Canvas, scene: Scene | list, label: str = ""
) -> Image.Image:
    """One picture of the recording at (fractional) frame ``frame``."""
    image = Image.new("RGB", canvas.size, BACKGROUND)
    draw = ImageDraw.Draw(image)
    if isinstance(scene, Scene):
        scene.draw(draw, canvas)
        scene.draw_signals(draw, canvas, rec.signals_at(frame))
    else:  # bare lane centre lines
        for line in scene:
            if len(line) >= 2:
                draw.line([tuple(p) for p in canvas.pixels(line)], fill=LANE, width=1)
    present, st = rec.state_at(frame)
    idx = np.flatnonzero(present)
    walkers = idx[rec.kind[idx] == ObjectKind.PEDESTRIAN]
    boxes = idx[rec.kind[idx] != ObjectKind.PEDESTRIAN]
    if boxes.size:
        corners = canvas.pixels(box_corners(st[0, boxes], st[1, boxes], st[2, boxes], rec.length[boxes], rec.width[boxes]))
        for k, poly in zip(boxes.tolist(), corners):
            colour = CYCLIST if rec.kind[k] == ObjectKind.CYCLIST else VEHICLE
            if rec.ego is not None and rec.ids[k] == rec.ego:
                colour = EGO
            draw.polygon([tuple(p) for p in poly], fill=colour)
    if walkers.size:
        centres = canvas.pixels(np.stack([st[0, walkers], st[1, walkers]], axis=1))
        r = np.maximum(0.5 * np.maximum(rec.length[walkers], rec.width[walkers]) * canvas.scale, 2.5)
        for (x, y), radius in zip(centres, r):
            draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=PEDESTRIAN)
    if label:
        counts = np.bincount(rec.kind[idx].astype(np.int64), minlength=len(ObjectKind))
        text = (f"{label}  vehicles {int(counts[:4].sum())}  cyclists {int(counts[ObjectKind.CYCLIST])}  "
                f"pedestrians {int(counts[ObjectKind.PEDESTRIAN])}")  # fmt: skip
        draw.text((4, 4), text, fill=TEXT)
    return image


def render(
    rec: Recording,
    out: Path,
    *,
    road_map=None,
    time: float | None = None,
    fps: float = 10.0,
    width: int = 800,
    start: float = 0.0,
    duration: float | None = None,
    max_frames: int = 20_000,
) -> int:
    """Write ``out``: a .png of the frame at ``time`` (s after the first frame; None: the middle),
    or a .gif/.mp4 of the window from ``start`` for ``duration`` seconds. Returns frames written."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".gif", ".mp4"):
        raise ReplayError(f"{out}: expected a .png image or a .gif or .mp4 video")
    if not (np.isfinite(fps) and fps > 0) or not 16 <= int(width):
        raise ReplayError(f"{out}: expected a positive frame rate and a width of at least 16 pixels")
    scene = Scene(rec, road_map)
    extent = rec.extent()
    under = tuple(road_map.bounds) if road_map is not None else scene.extent()
    if under is not None:
        extent = (min(extent[0], under[0]), min(extent[1], under[1]), max(extent[2], under[2]), max(extent[3], under[3]))
    canvas = Canvas(extent, width, top=LABEL_BAND)
    if suffix == ".png":
        t = rec.duration / 2 if time is None else time
        if not 0.0 <= t <= rec.duration + 1e-9:
            raise ReplayError(f"--time: the recording lasts {rec.duration:g} s, got {t:g}")
        out.parent.mkdir(parents=True, exist_ok=True)
        render_frame(rec, rec.frame_of(t), canvas, scene, f"t = {t:.1f} s").save(out)
        return 1
    if not 0.0 <= start <= rec.duration + 1e-9:
        raise ReplayError(f"--start: the recording lasts {rec.duration:g} s, got {start:g}")
    end = rec.duration if duration is None else min(rec.duration, start + duration)
    count = int(np.floor((end - start) * fps + 1e-9)) + 1
    if count > max_frames:
        raise ReplayError(f"--fps, --duration: {count} frames ({end - start:g} s at {fps:g} per second); at most "
                          f"{max_frames} are written")  # fmt: skip
    times = start + np.arange(count) / fps
    out.parent.mkdir(parents=True, exist_ok=True)
    frames = (render_frame(rec, rec.frame_of(t), canvas, scene, f"t = {t:.1f} s") for t in times)
    if suffix == ".gif":
        first = next(frames)
        first.save(out, save_all=True, append_images=list(frames), duration=max(int(1000 / fps), 1), loop=0)
    else:
        import imageio_ffmpeg

        size = (canvas.size[0] // 2 * 2, canvas.size[1] // 2 * 2)  # even sides for yuv420p
        writer = imageio_ffmpeg.write_frames(str(out), size, fps=fps, macro_block_size=1, quality=7)
        writer.send(None)
        for image in frames:
            writer.send(np.ascontiguousarray(np.asarray(image)[: size[1], : size[0]]))
        writer.close()
    return len(times)
