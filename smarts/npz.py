"""Reading and writing the .npz files the project writes many of (episode logs): standard .npz
that ``numpy.load`` reads, written and read faster than ``numpy.savez_compressed``/``numpy.load``.

A benchmark writes and reads back hundreds of logs of about fifty small arrays each. numpy spends
most of that time parsing each array's header (``ast.literal_eval``) and compressing at zlib's
default level, and ``zipfile`` about 40 microseconds per member on its own bookkeeping (a header
object, a member writer and its seeks, per-member checks on reading), as much as deflating a
log's arrays. Here the plain headers numpy writes are parsed with one pattern (anything else goes
through numpy's own reader), members are deflated at level 1 (a few percent larger), and the
archive's few records are packed and unpacked directly: one local header per member, the central
directory and its end record, without zip64 fields (a log is far below their limits; a larger
archive is written by ``zipfile``) and with a fixed timestamp, so the same arrays give the same
bytes. An archive that is not laid out that simply (another writer's, a damaged one) is read by
``zipfile``, which raises what it raises.
"""

from __future__ import annotations

import io
import math
import re
import struct
import zipfile
import zlib
from collections.abc import Mapping
from os import PathLike
from typing import BinaryIO

import numpy as np

COMPRESS_LEVEL = 1
_MAGIC = b"\x93NUMPY"
_PLAIN_HEADER = re.compile(
    r"\{'descr': '([<>|=][a-zA-Z]\d*)', 'fortran_order': (True|False), 'shape': \(([0-9, ]*)\), *\}"
)
# The zip records (APPNOTE 4.3.7, 4.3.12, 4.3.16): signature, versions, flags, method, DOS time and
# date, CRC-32, compressed and plain sizes, name and extra lengths, and (central) where the member is.
_LOCAL = struct.Struct("<IHHHHHIIIHH")
_CENTRAL = struct.Struct("<IHHHHHHIIIHHHHHII")
_END = struct.Struct("<IHHHHIIH")
_LOCAL_SIG, _CENTRAL_SIG, _END_SIG = 0x04034B50, 0x02014B50, 0x06054B50
_DEFLATED, _STORED = 8, 0
_VERSION = 20  # deflate
_MADE_BY = (3 << 8) | _VERSION  # Unix, as zipfile writes on Linux
_DOS_DATE = (0 << 9) | (1 << 5) | 1  # 1980-01-01 00:00, the earliest a zip can say
_FILE_MODE = 0o644 << 16
_UTF8_NAME = 0x800
_LIMIT = 0xFFFFFFFF  # sizes and offsets at or past this need zip64: zipfile writes those
_HEADERS: dict[tuple, bytes] = {}
"""numpy's .npy header by (dtype, Fortran order, shape): a log's arrays share a few shapes."""
_PARSED: dict[bytes, tuple] = {}
"""The other way: a plain header -> (dtype, shape, count, order)."""


def write_npz(fh: BinaryIO, arrays: Mapping[str, np.ndarray]) -> None:
    """``arrays`` as a compressed .npz into the open binary file ``fh`` (no pickled objects),
    written at once."""
    if len(arrays) >= 0xFFFF:  # more members than the end record counts: zipfile's zip64 records
        _write_with_zipfile(fh, arrays)
        return
    out, central = bytearray(), bytearray()
    for name, value in arrays.items():
        plain = _npy(np.asanyarray(value))
        packed = zlib.compress(plain, COMPRESS_LEVEL, wbits=-15)  # raw deflate, as zipfile's members
        member = f"{name}.npy"
        encoded = member.encode("utf-8")
        flags = 0 if member.isascii() else _UTF8_NAME
        crc, where = zlib.crc32(plain), len(out)
        if len(plain) >= _LIMIT or where + len(packed) >= _LIMIT:
            _write_with_zipfile(fh, arrays)
            return
        out += _LOCAL.pack(_LOCAL_SIG, _VERSION, flags, _DEFLATED, 0, _DOS_DATE, crc, len(packed), len(plain),
                           len(encoded), 0)  # fmt: skip
        out += encoded
        out += packed
        central += _CENTRAL.pack(_CENTRAL_SIG, _MADE_BY, _VERSION, flags, _DEFLATED, 0, _DOS_DATE, crc, len(packed),
                                 len(plain), len(encoded), 0, 0, 0, 0, _FILE_MODE, where)  # fmt: skip
        central += encoded
    start = len(out)
    out += central
    out += _END.pack(_END_SIG, 0, 0, len(arrays), len(arrays), len(central), start, 0)
    fh.write(out)


def _npy(array: np.ndarray) -> bytes:
    """The .npy file of ``array``, byte for byte what ``numpy.lib.format.write_array`` writes."""
    if array.dtype.hasobject:
        raise ValueError("Object arrays cannot be saved when allow_pickle=False")
    fortran = array.flags.f_contiguous and not array.flags.c_contiguous
    key = (array.dtype, fortran, array.shape)
    header = _HEADERS.get(key)
    if header is None:
        buffer = io.BytesIO()
        np.lib.format.write_array(buffer, array, allow_pickle=False)
        written = buffer.getvalue()
        if len(_HEADERS) > 1024:
            _HEADERS.clear()
        _HEADERS[key] = written[: len(written) - array.nbytes]
        return written
    return header + array.tobytes(order="F" if fortran else "C")


def _write_with_zipfile(fh: BinaryIO, arrays: Mapping[str, np.ndarray]) -> None:
    buffer = io.BytesIO()  # the zip writer seeks back over each member's header: not on a buffered file
    with zipfile.ZipFile(buffer, mode="w", compression=zipfile.ZIP_DEFLATED, compresslevel=COMPRESS_LEVEL) as zf:
        for name, value in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    fh.write(buffer.getbuffer())


def read_npz(path: str | PathLike) -> dict[str, np.ndarray]:
    """Every array of an .npz file, by name, as writable arrays (as ``numpy.load`` gives them).

    Raises ``OSError``, ``zipfile.BadZipFile`` or ``ValueError`` (a member that is not a numpy
    array, is truncated or damaged, or holds pickled objects), as ``numpy.load(allow_pickle=False)``
    would."""
    with open(path, "rb") as fh:
        data = fh.read()
    members = _members(data)
    if members is None:  # not laid out simply, or damaged: zipfile reads it (or says what is wrong)
        try:
            with zipfile.ZipFile(io.BytesIO(data)) as zf:
                members = [(info.filename, zf.read(info)) for info in zf.infolist()]
        except zlib.error as err:
            raise ValueError(f"a member's compressed data is damaged ({err})") from None
    return {(name[:-4] if name.endswith(".npy") else name): _array(body) for name, body in members}


def _members(data: bytes) -> list[tuple[str, bytes]] | None:
    """(name, contents) of each member of a one-part archive without a comment or zip64 fields whose
    records all agree and whose contents match their CRC-32; None for anything else."""
    end = len(data) - _END.size
    if end < 0 or data[end : end + 4] != b"PK\x05\x06":
        return None
    _, disk, first_disk, _, count, size, start, comment = _END.unpack_from(data, end)
    if disk or first_disk or comment or start + size != end:
        return None
    members, at = [], start
    for _ in range(count):
        if at + _CENTRAL.size > end:
            return None
        sig, _, _, flags, method, _, _, crc, packed, plain, name_len, extra_len, note_len, _, _, _, where = (
            _CENTRAL.unpack_from(data, at)
        )
        if sig != _CENTRAL_SIG or flags & 0x1 or method not in (_STORED, _DEFLATED) or _LIMIT in (packed, plain, where):
            return None
        name = data[at + _CENTRAL.size : at + _CENTRAL.size + name_len]
        at += _CENTRAL.size + name_len + extra_len + note_len
        if where + _LOCAL.size > start:
            return None
        local = _LOCAL.unpack_from(data, where)
        body = where + _LOCAL.size + local[9] + local[10]
        if local[0] != _LOCAL_SIG or data[where + _LOCAL.size : where + _LOCAL.size + local[9]] != name:
            return None
        if body + packed > start:
            return None
        raw = data[body : body + packed]
        if method == _DEFLATED:
            inflate = zlib.decompressobj(-15)
            try:
                raw = inflate.decompress(raw, plain or 1)  # (0 would mean: no limit)
            except zlib.error:
                return None
            if not inflate.eof:
                return None
        if len(raw) != plain or zlib.crc32(raw) != crc:
            return None
        members.append((name.decode("utf-8" if flags & _UTF8_NAME else "cp437"), raw))
    return members if at == end else None


def _array(data: bytes) -> np.ndarray:
    if data[:6] != _MAGIC or len(data) < 10:
        raise ValueError("a member is not a numpy array file")
    major = data[6]
    size_bytes = 2 if major == 1 else 4
    start = 8 + size_bytes
    header_len = int.from_bytes(data[8:start], "little")
    header = data[start : start + header_len]
    plain = _PARSED.get(header) if major in (1, 2) else None
    if plain is None:
        match = _PLAIN_HEADER.fullmatch(header.decode("latin1").strip())
        if match is None or major not in (1, 2):  # structured dtypes, unicode headers: numpy's reader
            return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
        descr, fortran, dims = match.groups()
        dtype = np.dtype(descr)
        if dtype.hasobject:
            raise ValueError("Object arrays cannot be loaded when allow_pickle=False")
        shape = tuple(int(d) for d in dims.replace(" ", "").split(",") if d)
        plain = (dtype, shape, math.prod(shape), "F" if fortran == "True" else "C")
        if len(_PARSED) > 1024:
            _PARSED.clear()
        _PARSED[header] = plain
    dtype, shape, count, order = plain
    body = memoryview(data)[start + header_len :]
    if len(body) != count * dtype.itemsize:
        raise ValueError(f"a member holds {len(body)} bytes of data, its header says {count * dtype.itemsize}")
    array = np.frombuffer(bytearray(body), dtype=dtype, count=count)
    return array.reshape(shape, order=order)
