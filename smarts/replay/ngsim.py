"""NGSIM vehicle trajectories (I-80, US-101, Lankershim, Peachtree) from their CSV files.

The published layout has one row per vehicle per 0.1 s frame: ``Vehicle_ID``, ``Frame_ID``,
``Local_X``/``Local_Y`` (feet, across and along the study area) or ``Global_X``/``Global_Y`` (state
plane feet), ``v_Length``, ``v_Width`` (feet), ``v_Class`` (1 motorcycle, 2 car, 3 truck),
``v_Vel``, ``v_Acc`` (feet/s, /s^2), ``Lane_ID``, ... Positions are the middle of the vehicle's
front edge. The reader converts to metres, lines the coordinates up with the map (pair of columns,
swap, flip, offset), derives heading and speed from positions smoothed over half a second (the
recorded positions jitter by decimetres from frame to frame) and moves each position back by half
the vehicle's length, to the centre of its box.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import VehicleType
from smarts.replay.recording import Recording, from_samples

FEET = 0.3048
"""Metres per foot."""
FRAME_SECONDS = 0.1
SMOOTH_FRAMES = 5
"""Frames (0.5 s) over which positions are averaged before heading and speed are taken from them."""
COLUMNS = {"local": ("Local_X", "Local_Y"), "global": ("Global_X", "Global_Y")}
REQUIRED = ("Vehicle_ID", "Frame_ID", "v_Length", "v_Width")
VEHICLE_CLASSES = {1: VehicleType.MOTORCYCLE, 2: VehicleType.PASSENGER, 3: VehicleType.TRUCK}


def read_ngsim(
    path: str | Path,
    *,
    coordinates: str = "local",
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
    smooth_frames: int = SMOOTH_FRAMES,
) -> Recording:
    """The tracks of an NGSIM trajectory CSV, in metres in the map frame."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    path = Path(path)
    if coordinates not in COLUMNS:
        raise ReplayError(f"{path}: coordinates: expected local or global, got {coordinates!r}")
    xcol, ycol = COLUMNS[coordinates]
    if not path.is_file():
        raise ReplayError(f"{path}: NGSIM trajectory file does not exist")
    header = _header(path)
    wanted = [*REQUIRED, xcol, ycol]
    missing = [c for c in wanted if c not in header]
    if missing:
        raise ReplayError(
            f"{path}: missing column(s) {', '.join(missing)} (coordinates: {coordinates} reads {xcol}, {ycol}); "
            f"the file has: {', '.join(header) or 'no header'}"
        )
    optional = [c for c in ("v_Class",) if c in header]
    types = {c: pa.float64() for c in (xcol, ycol, "v_Length", "v_Width")}
    types.update({"Vehicle_ID": pa.string(), "Frame_ID": pa.int64()})
    if optional:
        types["v_Class"] = pa.int64()
    try:
        table = pacsv.read_csv(
            path,
            convert_options=pacsv.ConvertOptions(include_columns=wanted + optional, column_types=types),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError) as err:
        raise ReplayError(f"{path}: {_conversion_problem(path, header, err)}") from None
    for name in wanted + optional:
        if table.column(name).null_count:
            row = int(np.flatnonzero(table.column(name).is_null().to_numpy(zero_copy_only=False))[0])
            raise ReplayError(f"{path}: column {name}: empty value in data row {row + 1}")
    vid = table.column("Vehicle_ID").to_numpy(zero_copy_only=False).astype(str)
    vid = np.char.strip(vid)
    frame = table.column("Frame_ID").to_numpy()
    x = table.column(xcol).to_numpy() * FEET
    y = table.column(ycol).to_numpy() * FEET
    length = table.column("v_Length").to_numpy() * FEET
    width = table.column("v_Width").to_numpy() * FEET
    for name, values in (("v_Length", length), ("v_Width", width)):
        if not (values > 0).all():
            row = int(np.flatnonzero(~(values > 0))[0])
            raise ReplayError(
                f"{path}: column {name}: expected a positive size in feet, got {values[row] / FEET:g} in data row {row + 1}"
            )
    if optional:
        cls = table.column("v_Class").to_numpy()
        vtype = np.array([VEHICLE_CLASSES.get(int(c), VehicleType.PASSENGER) for c in np.unique(cls)], np.int8)
        vtype = vtype[np.searchsorted(np.unique(cls), cls)]
    else:
        vtype = np.full(len(vid), int(VehicleType.PASSENGER), np.int8)
    x, y = align(x, y, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    try:
        rec = from_samples(
            str(path), "ngsim", vid, frame, x, y, None, None, length, width, vtype, FRAME_SECONDS,
            smooth_frames=smooth_frames,
        )  # fmt: skip
    except ReplayError as err:
        if "two samples" in str(err) and "Location" in header:  # the combined file of every site
            places = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(include_columns=["Location"]))
            names = sorted(set(places.column("Location").cast(pa.string()).to_pylist()) - {None})
            if len(names) > 1:
                raise ReplayError(f"{err}; the file holds several NGSIM sites (column Location: {', '.join(names)}), "
                                  "whose vehicle ids repeat: keep one site's rows") from None  # fmt: skip
        raise
    # the recorded point is the front edge's middle: the box centre is half a length behind it
    half = np.repeat(rec.length * 0.5, rec.count)
    rec.x -= half * np.cos(rec.heading)
    rec.y -= half * np.sin(rec.heading)
    return rec


def align(
    x: np.ndarray, y: np.ndarray, *, swap_xy: bool, flip_y: bool, offset: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Dataset coordinates in the map frame: swap the axes, negate y, then add ``offset``."""
    if swap_xy:
        x, y = y, x
    if flip_y:
        y = -y
    return x + float(offset[0]), y + float(offset[1])


def _header(path: Path) -> list[str]:
    with open(path, "rb") as f:
        line = f.readline().decode("utf-8", errors="replace").strip()
    return [c.strip().strip('"') for c in line.split(",")] if line else []


def _conversion_problem(path: Path, header: list[str], err: Exception) -> str:
    """pyarrow's conversion error told with the column's name and the first bad data row."""
    import re

    import pyarrow.csv as pacsv

    text = str(err).strip()
    match = re.search(r"CSV column #(\d+)", text)
    if match is None or int(match.group(1)) >= len(header):
        return text
    name = header[int(match.group(1))]
    column = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(include_columns=[name])).column(name)
    values = column.cast("string").to_pylist()
    expect = "an integer" if name == "Frame_ID" else "a number"
    for row, value in enumerate(values):
        try:
            int(value) if name == "Frame_ID" else float(value)
        except (TypeError, ValueError):
            return f"column {name}: expected {expect}, got {value!r} in data row {row + 1}"
    return f"column {name}: {text}"
