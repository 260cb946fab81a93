"""Reading and writing the .npz files the project writes many of (episode logs): standard .npz
that ``numpy.load`` reads, written and read faster than ``numpy.savez_compressed``/``numpy.load``.

A benchmark writes and reads back hundreds of logs of about a hundred small arrays each, where
numpy spends most of the time parsing each array's header (``ast.literal_eval``) and compressing
at zlib's default level. Here the plain headers numpy writes are parsed with one pattern (anything
else goes through numpy's own reader) and members are deflated at level 1 (a few percent larger).
"""

from __future__ import annotations

import io
import re
import zipfile
from collections.abc import Mapping
from typing import BinaryIO

import numpy as np

COMPRESS_LEVEL = 1
_MAGIC = b"\x93NUMPY"
_PLAIN_HEADER = re.compile(
    r"\{'descr': '([<>|=][a-zA-Z]\d*)', 'fortran_order': (True|False), 'shape': \(([0-9, ]*)\), *\}"
)


def write_npz(fh: BinaryIO, arrays: Mapping[str, np.ndarray]) -> None:
    """``arrays`` as a compressed .npz into the open binary file ``fh`` (no pickled objects).

    The archive is built in memory and written at once: the zip writer seeks back over each
    member's header when the member is done, and every seek of a buffered file flushes it."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, mode="w", compression=zipfile.ZIP_DEFLATED, compresslevel=COMPRESS_LEVEL) as zf:
        for name, value in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    fh.write(buffer.getbuffer())


def read_npz(path) -> dict[str, np.ndarray]:
    """Every array of an .npz file, by name, as writable arrays (as ``numpy.load`` gives them).

    Raises ``OSError``, ``zipfile.BadZipFile`` or ``ValueError`` (a member that is not a numpy
    array, is truncated, or holds pickled objects), as ``numpy.load(allow_pickle=False)`` would."""
    out: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            out[name] = _array(zf.read(info))
    return out


def _array(data: bytes) -> np.ndarray:
    if data[:6] != _MAGIC or len(data) < 10:
        raise ValueError("a member is not a numpy array file")
    major = data[6]
    size_bytes = 2 if major == 1 else 4
    start = 8 + size_bytes
    header_len = int.from_bytes(data[8:start], "little")
    match = _PLAIN_HEADER.fullmatch(data[start : start + header_len].decode("latin1").strip())
    if match is None or major not in (1, 2):  # structured dtypes, unicode headers: numpy's reader
        return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
    descr, fortran, dims = match.groups()
    dtype = np.dtype(descr)
    if dtype.hasobject:
        raise ValueError("Object arrays cannot be loaded when allow_pickle=False")
    shape = tuple(int(d) for d in dims.replace(" ", "").split(",") if d)
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    body = memoryview(data)[start + header_len :]
    if len(body) != count * dtype.itemsize:
        raise ValueError(f"a member holds {len(body)} bytes of data, its header says {count * dtype.itemsize}")
    array = np.frombuffer(bytearray(body), dtype=dtype, count=count)
    return array.reshape(shape, order="F" if fortran == "True" else "C")
