"""Top-down pictures of a recording: the road (surface, edges, painted lines, crosswalks, bike lanes,
stop signs and the recorded signal states), recorded vehicles as boxes, cyclists and pedestrians in
their own colours; one frame or many.

Used by ``smarts replay show`` to check a dataset lines up with its map before driving in it. A
picture of the whole recording fits its extent into the width asked for; a video can instead follow
one road user (the recording's ego by default) with a fixed-scale camera (:class:`FollowCanvas`):
at the size of a whole NGSIM site a car is a few pixels, at the camera's 6 px/m it is 27 by 11.
Every picture has a HUD band on top (time, frame, counts, the followed road user's speed), a
colour legend band below and a scale bar.

The drawing pieces (:class:`Scene` from a compiled map, :class:`FollowCanvas`, :func:`draw_hud`,
:func:`draw_legend`, :func:`draw_scale_bar`) are also what the simulator's follow-camera videos
(``smarts.viz.video``) draw with.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

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
"""Pixels above the road for the time and counts (one HUD line)."""
LINE_HEIGHT = 16
"""Pixels per HUD or legend line."""
FOLLOW_SCALE = 6.0
"""Pixels per metre of the follow camera: a 4.5 m car is 27 pixels long."""
FOLLOW_SIZE = (640, 400)
"""Pixels of a follow-camera view (the road part; the HUD and legend bands come on top)."""
HUD_FILL = (16, 18, 22)
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

    def view_box(self) -> tuple[float, float, float, float]:
        """xmin, ymin, xmax, ymax in metres of what the picture shows."""
        w, h = self.size
        return (self.x0, self.y1 - (h - self.top) / self.scale, self.x0 + w / self.scale, self.y1)


class FollowCanvas(Canvas):
    """A fixed-scale window of ``view`` pixels (the road part) that :meth:`centre_on` moves over
    the map; ``top`` pixels above it for the HUD and ``bottom`` below for the legend."""

    def __init__(self, view: tuple[int, int] = FOLLOW_SIZE, scale: float = FOLLOW_SCALE, top: int = 2 * LINE_HEIGHT + 4,
                 bottom: int = LINE_HEIGHT + 8):  # fmt: skip
        self.scale = float(scale)
        self.top = int(top)
        self.view = (int(view[0]), int(view[1]))
        self.bottom = int(bottom)
        self.size = (self.view[0], self.top + self.view[1] + self.bottom)
        self.centre_on(0.0, 0.0)

    def centre_on(self, x: float, y: float) -> None:
        self.x0 = float(x) - 0.5 * self.view[0] / self.scale
        self.y1 = float(y) + 0.5 * self.view[1] / self.scale

    def view_box(self) -> tuple[float, float, float, float]:
        return (self.x0, self.y1 - self.view[1] / self.scale, self.x0 + self.view[0] / self.scale, self.y1)


def font(size: int = 13) -> ImageFont.ImageFont:
    """The HUD's font: Pillow's own scalable one (no system fonts needed)."""
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # a Pillow without FreeType: its bitmap font
        return ImageFont.load_default()


def draw_hud(draw: ImageDraw.ImageDraw, width: int, lines: list[str], top: int = 0) -> None:
    """Text lines on a dark band across the top ``len(lines) * LINE_HEIGHT + 4`` pixels."""
    draw.rectangle([0, top, width, top + len(lines) * LINE_HEIGHT + 3], fill=HUD_FILL)
    f = font()
    for k, line in enumerate(lines):
        draw.text((6, top + 2 + k * LINE_HEIGHT), line, fill=TEXT, font=f)


def draw_legend(draw: ImageDraw.ImageDraw, width: int, y: int, items: list[tuple[str, tuple]]) -> None:
    """A row of colour swatches with their names on a dark band from pixel row ``y`` down."""
    draw.rectangle([0, y, width, y + LINE_HEIGHT + 8], fill=HUD_FILL)
    f = font(12)
    x = 6
    for name, colour in items:
        draw.rectangle([x, y + 6, x + 11, y + 17], fill=colour, outline=(0, 0, 0))
        draw.text((x + 15, y + 4), name, fill=TEXT, font=f)
        x += 15 + int(draw.textlength(name, font=f)) + 12
        if x > width - 40:
            break


def draw_scale_bar(draw: ImageDraw.ImageDraw, canvas: Canvas, bottom: int) -> None:
    """A bar of a round number of metres (about a sixth of the width) at the lower right."""
    w = canvas.size[0]
    metres = 1.0
    for step in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000):
        if step * canvas.scale <= w / 6:
            metres = float(step)
    length = metres * canvas.scale
    x1, y = w - 10, bottom - 10
    draw.rectangle([x1 - length - 8, y - 21, x1 + 6, y + 7], fill=HUD_FILL)  # readable over any road
    draw.line([(x1 - length, y), (x1, y)], fill=WHITE, width=3)
    draw.line([(x1 - length, y - 4), (x1 - length, y + 4)], fill=WHITE, width=2)
    draw.line([(x1, y - 4), (x1, y + 4)], fill=WHITE, width=2)
    label = f"{metres:g} m"
    f = font(12)
    draw.text((x1 - length / 2 - draw.textlength(label, font=f) / 2, y - 18), label, fill=WHITE, font=f)


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

    def __init__(self, rec: Recording | None, road_map=None):
        """From ``road_map`` (a compiled map) when given, else from the recording's own map."""
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
            if rm.lane_internal[lane]:  # junction lanes cross each other: their surface only
                continue
            outer_left = rm.lane_left[lane] < 0
            self.lines.append((_side(line, half), EDGE if outer_left else WHITE, not outer_left))
            if rm.lane_right[lane] < 0:
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

    def _visible(self, group: str, shapes: list, canvas: Canvas) -> list[bool]:
        """Which of ``shapes`` (arrays or tuples starting with one) reach into the canvas's view
        (their boxes are computed once: a follow camera draws a small part of a large map)."""
        boxes = self.__dict__.setdefault("_boxes", {})
        if group not in boxes or len(boxes[group]) != len(shapes):
            pts = [np.asarray(s[0] if isinstance(s, tuple) else s, dtype=np.float64).reshape(-1, 2) for s in shapes]
            boxes[group] = np.array([[p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()] if len(p) else
                                     [np.inf, np.inf, -np.inf, -np.inf] for p in pts]).reshape(-1, 4)  # fmt: skip
        b = boxes[group]
        x0, y0, x1, y1 = canvas.view_box()
        pad = 2.0
        return ((b[:, 2] >= x0 - pad) & (b[:, 0] <= x1 + pad) & (b[:, 3] >= y0 - pad) & (b[:, 1] <= y1 + pad)).tolist()

    def draw(self, draw: ImageDraw.ImageDraw, canvas: Canvas) -> None:
        px = max(canvas.scale, 1e-9)
        for poly, seen in zip(self.surfaces, self._visible("surfaces", self.surfaces, canvas)):
            if len(poly) >= 3 and seen:
                draw.polygon([tuple(p) for p in canvas.pixels(poly)], fill=SURFACE)
        fills = {CROSSWALK: CROSSWALK_FILL, BIKE_LANE: BIKE_FILL}
        for (poly, kind), seen in zip(self.marks, self._visible("marks", self.marks, canvas)):
            if len(poly) < 3 or not seen:
                continue
            points = [tuple(p) for p in canvas.pixels(poly)]
            if kind == SPEED_BUMP:
                draw.polygon(points, outline=BUMP, width=max(int(0.3 * px), 1))
            else:
                draw.polygon(points, fill=fills.get(kind, CROSSWALK_FILL))
            if kind == CROSSWALK:  # zebra stripes across its long side
                self._stripes(draw, canvas, np.asarray(poly))
        for line, seen in zip(self.centres, self._visible("centres", self.centres, canvas)):
            if len(line) >= 2 and seen:
                draw.line([tuple(p) for p in canvas.pixels(line)], fill=LANE, width=1)
        width = max(int(round(0.15 * px)), 1)
        for (line, colour, dashed), seen in zip(self.lines, self._visible("lines", self.lines, canvas)):
            if len(line) < 2 or not seen:
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


LEGEND = [("vehicle", VEHICLE), ("ego / followed", EGO), ("cyclist", CYCLIST), ("pedestrian", PEDESTRIAN),
          ("signal red", SIGNAL_COLOURS[1]), ("yellow", SIGNAL_COLOURS[2]), ("green", SIGNAL_COLOURS[3])]  # fmt: skip


def render_frame(
    rec: Recording, frame: float, canvas: Canvas, scene: Scene | list, label: str = "", follow: str | None = None
) -> Image.Image:
    """One picture of the recording at (fractional) frame ``frame``. ``follow``: the road user the
    canvas (a :class:`FollowCanvas`) is centred on and the HUD reports."""
    present, st = rec.state_at(frame)
    followed = rec.index_of.get(follow) if follow is not None else None
    if isinstance(canvas, FollowCanvas) and followed is not None and present[followed]:
        canvas.centre_on(st[0, followed], st[1, followed])
    image = Image.new("RGB", canvas.size, BACKGROUND)
    draw = ImageDraw.Draw(image)
    if isinstance(scene, Scene):
        scene.draw(draw, canvas)
        scene.draw_signals(draw, canvas, rec.signals_at(frame))
    else:  # bare lane centre lines
        for line in scene:
            if len(line) >= 2:
                draw.line([tuple(p) for p in canvas.pixels(line)], fill=LANE, width=1)
    idx = np.flatnonzero(present)
    walkers = idx[rec.kind[idx] == ObjectKind.PEDESTRIAN]
    boxes = idx[rec.kind[idx] != ObjectKind.PEDESTRIAN]
    highlight = followed if followed is not None else (rec.index_of.get(rec.ego) if rec.ego is not None else None)
    if boxes.size:
        corners = canvas.pixels(
            box_corners(st[0, boxes], st[1, boxes], st[2, boxes], rec.length[boxes], rec.width[boxes])
        )
        for k, poly in zip(boxes.tolist(), corners):
            colour = CYCLIST if rec.kind[k] == ObjectKind.CYCLIST else VEHICLE
            if k == highlight:
                colour = EGO
            draw.polygon([tuple(p) for p in poly], fill=colour, outline=WHITE if k == highlight else None)
    if walkers.size:
        centres = canvas.pixels(np.stack([st[0, walkers], st[1, walkers]], axis=1))
        r = np.maximum(0.5 * np.maximum(rec.length[walkers], rec.width[walkers]) * canvas.scale, 2.5)
        for (x, y), radius in zip(centres, r):
            draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=PEDESTRIAN)
    bottom = canvas.size[1] - getattr(canvas, "bottom", 0)
    draw_scale_bar(draw, canvas, bottom)
    lines = []
    if label:
        counts = np.bincount(rec.kind[idx].astype(np.int64), minlength=len(ObjectKind))
        lines.append(f"{label}  frame {frame:.0f}  vehicles {int(counts[:4].sum())}  cyclists "
                     f"{int(counts[ObjectKind.CYCLIST])}  pedestrians {int(counts[ObjectKind.PEDESTRIAN])}")  # fmt: skip
    if followed is not None and isinstance(canvas, FollowCanvas):
        name = f"{follow} (ego)" if follow == rec.ego else str(follow)
        lines.append(f"following {name}: " + (f"{st[3, followed]:.1f} m/s ({3.6 * st[3, followed]:.0f} km/h)"
                                               if present[followed] else "not recorded at this time"))  # fmt: skip
    if lines:
        draw_hud(draw, canvas.size[0], lines[: max(1, canvas.top // LINE_HEIGHT)])
    if getattr(canvas, "bottom", 0):
        draw_legend(draw, canvas.size[0], bottom, LEGEND)
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
    follow: str | None = "auto",
) -> int:
    """Write ``out``: a .png of the frame at ``time`` (s after the first frame; None: the middle),
    or a .gif/.mp4 of the window from ``start`` for ``duration`` seconds. Returns frames written.

    ``follow``: a road user's id to follow with a fixed-scale camera, ``"ego"`` for the
    recording's ego, ``"auto"`` for the ego in a video of a recording that has one (a picture, or
    a recording without an ego, shows everything), None for the whole recording."""
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
        extent = (
            min(extent[0], under[0]),
            min(extent[1], under[1]),
            max(extent[2], under[2]),
            max(extent[3], under[3]),
        )
    if follow == "auto":
        follow = rec.ego if suffix != ".png" else None
    elif follow == "ego":
        if rec.ego is None:
            raise ReplayError("--follow ego: this recording has no ego; give a road user's id")
        follow = rec.ego
    if follow is not None and follow not in rec.index_of:
        raise ReplayError(f"--follow {follow}: no road user of that id in the recording (ego: {rec.ego or 'none'})")
    if follow is not None:
        canvas = FollowCanvas((width, int(width * 5 / 8) // 2 * 2))
    else:
        canvas = Canvas(extent, width, top=LABEL_BAND)
        canvas.bottom = LINE_HEIGHT + 8
        canvas.size = (canvas.size[0], canvas.size[1] + canvas.bottom)
    if suffix == ".png":
        t = rec.duration / 2 if time is None else time
        if not 0.0 <= t <= rec.duration + 1e-9:
            raise ReplayError(f"--time: the recording lasts {rec.duration:g} s, got {t:g}")
        out.parent.mkdir(parents=True, exist_ok=True)
        render_frame(rec, rec.frame_of(t), canvas, scene, f"t = {t:.1f} s", follow).save(out)
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
    frames = (render_frame(rec, rec.frame_of(t), canvas, scene, f"t = {t:.1f} s", follow) for t in times)
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
