"""NGSIM vehicle trajectories (I-80, US-101, Lankershim, Peachtree) as published.

Two layouts are read:

- the CSV with a header row (the data portal's file, every site in one with a ``Location`` column,
  or one site's): ``Vehicle_ID``, ``Frame_ID``, ``Local_X``/``Local_Y`` (feet, across and along the
  study area) or ``Global_X``/``Global_Y`` (state plane feet), ``v_Length`` (the portal spells
  ``v_length``; names are matched whatever their capitalisation), ``v_Width`` (feet), ``v_Class``
  (1 motorcycle, 2 car, 3 truck), ...;
- the original whitespace-separated ``.txt`` files without a header, whose first eleven columns are
  vehicle id, frame id, total frames, global time, local x, local y, global x, global y, length,
  width and class (the arterial sites add more columns after them).

One row per vehicle per 0.1 s frame; positions are the middle of the vehicle's front edge. The
reader keeps one site (``location``; the portal's file holds four whose ids repeat), converts to
metres, lines the coordinates up with the map (pair of columns, swap, flip, offset), derives heading
and speed from positions smoothed over half a second (the recorded positions jitter by decimetres
from frame to frame; headings come from chords longer than that jitter, so queued and crawling cars
keep pointing along their motion: ``recording.kinematics_from_positions``) and moves each position
back by half the vehicle's length, to the centre of its box.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import VehicleType
from smarts.replay.recording import MAX_COORDINATE, MAX_SIZE, Recording, check_values, from_samples

FEET = 0.3048
"""Metres per foot."""
FRAME_SECONDS = 0.1
SMOOTH_FRAMES = 5
"""Frames (0.5 s) over which positions are averaged before heading and speed are taken from them."""
COLUMNS = {"local": ("Local_X", "Local_Y"), "global": ("Global_X", "Global_Y")}
REQUIRED = ("Vehicle_ID", "Frame_ID", "v_Length", "v_Width")
VEHICLE_CLASSES = {1: VehicleType.MOTORCYCLE, 2: VehicleType.PASSENGER, 3: VehicleType.TRUCK}
TXT_COLUMNS = {"Vehicle_ID": 0, "Frame_ID": 1, "Local_X": 4, "Local_Y": 5, "Global_X": 6, "Global_Y": 7,
               "v_Length": 8, "v_Width": 9, "v_Class": 10}  # fmt: skip
"""Positions of the columns read in the header-less ``.txt`` layout."""


def read_ngsim(
    path: str | Path,
    *,
    coordinates: str = "local",
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
    smooth_frames: int = SMOOTH_FRAMES,
    location: str | None = None,
) -> Recording:
    """The tracks of an NGSIM trajectory file (CSV with a header, or the header-less ``.txt``), in
    metres in the map frame; ``location`` keeps the rows of one site of a file with a ``Location``
    column."""
    path = Path(path)
    if coordinates not in COLUMNS:
        raise ReplayError(f"{path}: coordinates: expected local or global, got {coordinates!r}")
    xcol, ycol = COLUMNS[coordinates]
    check_file(path, "ngsim")
    first = _first_line(path)
    if not first.strip():
        raise ReplayError(f"{path}: empty file; expected NGSIM trajectory rows")
    if re.search(r"[A-Za-z_]{2,}", first):  # a header row
        cols, rows = _read_csv(path, xcol, ycol, coordinates, location)
    else:
        if location is not None:
            raise ReplayError(f"{path}: location {location!r}: the file has no Location column (the original "
                              ".txt layout holds one site)")  # fmt: skip
        cols, rows = _read_txt(path, first, xcol, ycol)
    vid = np.char.strip(cols["Vehicle_ID"].astype(str))
    frame = cols["Frame_ID"]
    for name, bound in ((xcol, MAX_COORDINATE), (ycol, MAX_COORDINATE)):
        check_values(str(path), name, cols[name], bound=bound, rows=rows)
    for name in ("v_Length", "v_Width"):
        check_values(str(path), name, cols[name], bound=MAX_SIZE / FEET, positive=True, rows=rows)
    x, y = cols[xcol] * FEET, cols[ycol] * FEET
    length, width = cols["v_Length"] * FEET, cols["v_Width"] * FEET
    if "v_Class" in cols:
        cls = cols["v_Class"]
        classes = np.unique(cls)
        vtype = np.array([VEHICLE_CLASSES.get(int(c), VehicleType.PASSENGER) for c in classes], np.int8)
        vtype = vtype[np.searchsorted(classes, cls)]
    else:
        vtype = np.full(len(vid), int(VehicleType.PASSENGER), np.int8)
    x, y = align(x, y, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    rec = from_samples(
        str(path), "ngsim", vid, frame, x, y, None, None, length, width, vtype, FRAME_SECONDS,
        smooth_frames=smooth_frames,
    )  # fmt: skip
    # the recorded point is the front edge's middle: the box centre is half a length behind it
    half = np.repeat(rec.length * 0.5, rec.count)
    rec.x -= half * np.cos(rec.heading)
    rec.y -= half * np.sin(rec.heading)
    return rec


def check_file(path: Path, fmt: str) -> None:
    """A path that is not a file of the format, told in one line: a folder, a missing file, or a
    file of another dataset's format."""
    if path.is_dir():
        what = {"ngsim": "an NGSIM trajectory file (.csv or .txt)", "waymo": "a TFRecord file of Scenario records"}
        raise ReplayError(f"{path}: is a folder; --format {fmt} reads {what.get(fmt, 'a file')} (name the file)")
    if not path.is_file():
        raise ReplayError(f"{path}: {fmt} recording does not exist")
    with open(path, "rb") as f:
        head = f.read(16)
    kind = sniff(head)
    expected = {"ngsim": ("text",), "waymo": ("tfrecord",)}.get(fmt, ())
    if kind is not None and kind not in expected:
        hint = {"parquet": "a parquet file (Argoverse 2 scenarios are read with --format argoverse2)",
                "tfrecord": "a TFRecord file (Waymo Open Motion scenarios are read with --format waymo)",
                "zip": "a zip archive (extract it first)", "gzip": "a gzip file (decompress it first)",
                "text": "a text file (NGSIM trajectories are read with --format ngsim)"}  # fmt: skip
        wanted = "an NGSIM trajectory file" if fmt == "ngsim" else f"a {fmt} file"
        raise ReplayError(f"{path}: is {hint[kind]}, not {wanted}")


def sniff(head: bytes) -> str | None:
    """What the first bytes of a file say it is: parquet, tfrecord, zip, gzip, text or None."""
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(b"PK\x03\x04"):
        return "zip"
    if head.startswith(b"\x1f\x8b"):
        return "gzip"
    if len(head) >= 12:
        from smarts.replay.tfrecord import masked_crc

        if masked_crc(head[:8]) == int.from_bytes(head[8:12], "little"):
            return "tfrecord"
    if head and all(32 <= b < 127 or b in (9, 10, 13) for b in head.lstrip(b"\xef\xbb\xbf")):
        return "text"
    return None


def align(
    x: np.ndarray, y: np.ndarray, *, swap_xy: bool, flip_y: bool, offset: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Dataset coordinates in the map frame: swap the axes, negate y, then add ``offset``."""
    if swap_xy:
        x, y = y, x
    if flip_y:
        y = -y
    return x + float(offset[0]), y + float(offset[1])


def _first_line(path: Path) -> str:
    with open(path, "rb") as f:
        return f.readline(1 << 16).decode("utf-8", errors="replace").lstrip("\ufeff")


def _header(line: str) -> list[str]:
    return [c.strip().strip('"') for c in line.strip().split(",")] if line.strip() else []


def _read_csv(
    path: Path, xcol: str, ycol: str, coordinates: str, location: str | None
) -> tuple[dict, np.ndarray | None]:
    """The columns of a CSV with a header (names matched whatever their capitalisation) and the
    data row number of each kept row (None when every row is kept)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    header = _header(_first_line(path))
    actual = {name.lower(): name for name in header}
    wanted = [*REQUIRED, xcol, ycol]
    missing = [c for c in wanted if c.lower() not in actual]
    if missing:
        raise ReplayError(
            f"{path}: missing column(s) {', '.join(missing)} (coordinates: {coordinates} reads {xcol}, {ycol}); "
            f"the file has: {', '.join(header) or 'no header'}"
        )
    names = {c: actual[c.lower()] for c in wanted}
    if "v_class" in actual:
        names["v_Class"] = actual["v_class"]
    types = {names[c]: pa.float64() for c in (xcol, ycol, "v_Length", "v_Width")}
    types.update({names["Vehicle_ID"]: pa.string(), names["Frame_ID"]: pa.int64()})
    if "v_Class" in names:
        types[names["v_Class"]] = pa.int64()
    read = list(names.values())
    site = actual.get("location")
    if site is not None:
        types[site] = pa.string()
        read.append(site)
    elif location is not None:
        raise ReplayError(f"{path}: location {location!r}: the file has no Location column")
    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(use_threads=True),
            convert_options=pacsv.ConvertOptions(include_columns=read, column_types=types, null_values=[""],
                                                 strings_can_be_null=True),
        )  # fmt: skip
    except (pa.ArrowInvalid, pa.ArrowTypeError) as err:
        raise ReplayError(f"{path}: {_conversion_problem(path, header, err)}") from None
    for name in read:
        if table.column(name).null_count:
            row = int(np.flatnonzero(table.column(name).is_null().to_numpy(zero_copy_only=False))[0])
            raise ReplayError(f"{path}: column {name}: empty value in data row {row + 1}")
    rows = None
    if site is not None:
        places = np.char.lower(np.char.strip(np.asarray(table.column(site).to_numpy(zero_copy_only=False), dtype=str)))
        found = sorted(set(places.tolist()))
        if location is None:
            if len(found) > 1:
                raise ReplayError(f"{path}: the file holds several NGSIM sites (column {site}: {', '.join(found)}), "
                                  "whose vehicle ids repeat: choose one with replay.scenario (--location)")  # fmt: skip
        else:
            keep = places == location.strip().lower()
            if not keep.any():
                raise ReplayError(f"{path}: location {location!r}: no rows of that site (column {site}: "
                                  f"{', '.join(found)})")  # fmt: skip
            rows = np.flatnonzero(keep) + 1
            table = table.filter(pa.array(keep))
    cols = {c: table.column(n).to_numpy(zero_copy_only=False) for c, n in names.items()}
    return cols, rows


def _read_txt(path: Path, first: str, xcol: str, ycol: str) -> tuple[dict, None]:
    """The columns of the original header-less layout (whitespace- or comma-separated)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    sep = "," if "," in first else None
    width = len(first.split(sep))
    if width < len(TXT_COLUMNS) + 2:
        raise ReplayError(
            f"{path}: line 1 has {width} column(s); the NGSIM trajectory layout without a header has at least 11 "
            "(vehicle id, frame id, total frames, global time, local x, local y, global x, global y, length, "
            "width, class)"
        )
    data = path.read_bytes()
    if sep is None:  # runs of blanks -> one comma, none at a line's start or end
        data = re.sub(rb"[ \t]+", b",", data)
        data = re.sub(rb"(?m)^,|,(?=\r?$)", b"", data)
    names = [f"c{k}" for k in range(width)]
    wanted = ["Vehicle_ID", "Frame_ID", xcol, ycol, "v_Length", "v_Width", "v_Class"]
    types = {f"c{TXT_COLUMNS[c]}": pa.float64() for c in wanted}
    types[f"c{TXT_COLUMNS['Vehicle_ID']}"] = pa.string()
    types[f"c{TXT_COLUMNS['Frame_ID']}"] = pa.int64()
    types[f"c{TXT_COLUMNS['v_Class']}"] = pa.int64()
    import io

    try:
        table = pacsv.read_csv(
            io.BytesIO(data),
            read_options=pacsv.ReadOptions(column_names=names),
            convert_options=pacsv.ConvertOptions(include_columns=list(types), column_types=types, null_values=[""]),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError) as err:
        raise ReplayError(f"{path}: {_txt_problem(data, width, wanted, err)}") from None
    cols = {}
    for c in wanted:
        column = table.column(f"c{TXT_COLUMNS[c]}")
        if column.null_count:
            row = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
            raise ReplayError(f"{path}: column {TXT_COLUMNS[c] + 1} ({c}): empty value in line {row + 1}")
        cols[c] = column.to_numpy(zero_copy_only=False)
    return cols, None


def _txt_problem(data: bytes, width: int, wanted: list[str], err: Exception) -> str:
    """pyarrow's error on a header-less file told with the line and column at fault."""
    for number, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), start=1):
        cells = line.split(",")
        if not line.strip():
            continue
        if len(cells) != width:
            return f"line {number}: expected {width} columns (as line 1), got {len(cells)}"
        for c in wanted:
            k = TXT_COLUMNS[c]
            try:
                int(cells[k]) if c in ("Frame_ID", "v_Class") else float(cells[k])
            except ValueError:
                if c == "Vehicle_ID":
                    continue
                expected = "an integer" if c in ("Frame_ID", "v_Class") else "a number"
                return f"column {k + 1} ({c}): expected {expected}, got {cells[k]!r} in line {number}"
    return str(err).strip()


def _conversion_problem(path: Path, header: list[str], err: Exception) -> str:
    """pyarrow's conversion error told with the column's name and the first bad data row."""
    import pyarrow.csv as pacsv

    text = str(err).strip()
    match = re.search(r"CSV column #(\d+)", text)
    if match is None or int(match.group(1)) >= len(header):
        return text
    name = header[int(match.group(1))]
    column = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(include_columns=[name])).column(name)
    values = column.cast("string").to_pylist()
    integer = name.lower() in ("frame_id", "v_class")
    expect = "an integer" if integer else "a number"
    for row, value in enumerate(values):
        try:
            int(value) if integer else float(value)
        except (TypeError, ValueError):
            return f"column {name}: expected {expect}, got {value!r} in data row {row + 1}"
    return f"column {name}: {text}"
