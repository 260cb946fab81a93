"""Top-down pictures of a recording: lanes in grey, recorded vehicles as boxes, one frame or many.

Used by ``smarts replay show`` to check a dataset lines up with its map before driving in it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from smarts.core.errors import ReplayError
from smarts.core.geometry import box_corners
from smarts.replay.recording import Recording

BACKGROUND = (24, 26, 30)
LANE = (96, 100, 108)
VEHICLE = (80, 170, 255)
TEXT = (230, 230, 230)


class Canvas:
    """World-to-pixel transform fitting ``extent`` (xmin, ymin, xmax, ymax) in ``width`` pixels."""

    def __init__(self, extent: tuple[float, float, float, float], width: int, margin: float = 5.0):
        xmin, ymin, xmax, ymax = extent
        self.x0, self.y1 = xmin - margin, ymax + margin
        span_x = max(xmax - xmin + 2 * margin, 1.0)
        span_y = max(ymax - ymin + 2 * margin, 1.0)
        self.scale = width / span_x
        self.size = (int(width), max(int(round(span_y * self.scale)), 16))
        if self.size[1] > 4 * width:  # a tall recording: fit the height instead
            self.scale = 4 * width / span_y
            self.size = (max(int(round(span_x * self.scale)), 16), 4 * width)

    def pixels(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([(xy[..., 0] - self.x0) * self.scale, (self.y1 - xy[..., 1]) * self.scale], axis=-1)


def lane_lines(road_map) -> list[np.ndarray]:
    """Centre polylines of a compiled ``RoadMap``."""
    off = road_map.lane_point_offsets
    return [road_map.points[off[i] : off[i + 1]] for i in range(len(off) - 1)]


def render_frame(
    rec: Recording, frame: float, canvas: Canvas, lanes: list[np.ndarray], label: str = ""
) -> Image.Image:
    image = Image.new("RGB", canvas.size, BACKGROUND)
    draw = ImageDraw.Draw(image)
    for line in lanes:
        if len(line) >= 2:
            draw.line([tuple(p) for p in canvas.pixels(line)], fill=LANE, width=1)
    present, st = rec.state_at(frame)
    idx = np.flatnonzero(present)
    if idx.size:
        corners = canvas.pixels(box_corners(st[0, idx], st[1, idx], st[2, idx], rec.length[idx], rec.width[idx]))
        for poly in corners:
            draw.polygon([tuple(p) for p in poly], fill=VEHICLE)
    if label:
        draw.text((4, 4), label, fill=TEXT)
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
) -> int:
    """Write ``out``: a .png of the frame at ``time`` (s after the first frame; None: the middle),
    or a .gif/.mp4 of the window from ``start`` for ``duration`` seconds. Returns frames written."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".gif", ".mp4"):
        raise ReplayError(f"{out}: expected a .png image or a .gif or .mp4 video")
    if road_map is not None:
        lanes = lane_lines(road_map)
    elif rec.road_map is not None:  # the dataset's own lanes
        lanes = list(rec.road_map.polylines)
    else:
        lanes = []
    extent = rec.extent()
    if road_map is not None:
        b = road_map.bounds
        extent = (min(extent[0], b[0]), min(extent[1], b[1]), max(extent[2], b[2]), max(extent[3], b[3]))
    canvas = Canvas(extent, width)
    out.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".png":
        t = rec.duration / 2 if time is None else time
        frame = rec.start_frame + t / rec.dt
        render_frame(rec, frame, canvas, lanes, f"t = {t:.1f} s").save(out)
        return 1
    end = rec.duration if duration is None else min(rec.duration, start + duration)
    times = np.arange(start, end + 1e-9, 1.0 / fps)
    frames = (render_frame(rec, rec.start_frame + t / rec.dt, canvas, lanes, f"t = {t:.1f} s") for t in times)
    if suffix == ".gif":
        first = next(frames)
        first.save(out, save_all=True, append_images=list(frames), duration=int(1000 / fps), loop=0)
    else:
        import imageio_ffmpeg

        size = (canvas.size[0] // 2 * 2, canvas.size[1] // 2 * 2)  # even sides for yuv420p
        writer = imageio_ffmpeg.write_frames(str(out), size, fps=fps, macro_block_size=1, quality=7)
        writer.send(None)
        for image in frames:
            writer.send(np.ascontiguousarray(np.asarray(image)[: size[1], : size[0]]))
        writer.close()
    return len(times)
