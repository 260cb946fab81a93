"""Reading TFRecord files without TensorFlow.

A TFRecord file is a sequence of records, each: the data length as a little-endian uint64, the
masked CRC-32C of those 8 bytes (uint32), the data, and the masked CRC-32C of the data (uint32). A
masked CRC is ``((crc >> 15) | (crc << 17)) + 0xA282EAD8`` modulo 2**32. Both checksums are checked,
so a truncated or corrupted file is reported with its record number and byte offset instead of
being parsed into garbage.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from smarts.compiled import njit
from smarts.core.errors import ReplayError

_MASK_DELTA = 0xA282EAD8
MAX_RECORD_BYTES = 1 << 30
"""Bytes one record may hold (a Waymo Open Motion scenario is a few MB): a larger length in a
header is refused before anything is allocated."""


def _crc32c_table() -> np.ndarray:
    poly = 0x82F63B78  # CRC-32C (Castagnoli), reflected
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ poly if c & 1 else c >> 1
        table[i] = c
    return table


_TABLE = _crc32c_table()


@njit(nogil=True)
def _crc32c(data, table):  # pragma: no cover - compiled
    crc = np.uint32(0xFFFFFFFF)
    for b in data:
        crc = table[(crc ^ b) & 0xFF] ^ (crc >> np.uint32(8))
    return crc ^ np.uint32(0xFFFFFFFF)


def crc32c(data: bytes) -> int:
    return int(_crc32c(np.frombuffer(data, dtype=np.uint8), _TABLE))


def masked_crc(data: bytes) -> int:
    crc = crc32c(data)
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


def write_records(path: str | Path, records: list[bytes]) -> None:
    """Write ``records`` as a TFRecord file (used to make small test files and to export)."""
    with open(path, "wb") as f:
        for data in records:
            length = struct.pack("<Q", len(data))
            f.write(length + struct.pack("<I", masked_crc(length)) + data + struct.pack("<I", masked_crc(data)))


def read_records(path: str | Path) -> Iterator[bytes]:
    """The records of a TFRecord file, checked; a bad or cut record raises ``ReplayError`` naming
    the file, the record (0-based) and its byte offset."""
    path = Path(path)
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        index = 0
        while True:
            offset = f.tell()
            header = f.read(12)
            if not header:
                return
            where = f"{path}: record {index} at byte {offset}"
            if len(header) < 12:
                raise ReplayError(f"{where}: truncated (a {len(header)}-byte header, expected 12 bytes)")
            length_bytes, length_crc = header[:8], struct.unpack("<I", header[8:])[0]
            if masked_crc(length_bytes) != length_crc:
                raise ReplayError(f"{where}: the length's checksum does not match (not a TFRecord file, or corrupted)")
            (length,) = struct.unpack("<Q", length_bytes)
            after = size - offset - 12
            if length + 4 > after:  # checked before reading: a header may claim any size
                raise ReplayError(
                    f"{where}: truncated (the header claims {length} data bytes and a 4-byte checksum; "
                    f"{max(after, 0)} bytes follow it)"
                )
            if length > MAX_RECORD_BYTES:
                raise ReplayError(
                    f"{where}: a {length}-byte record; at most {MAX_RECORD_BYTES} bytes are read per record"
                )
            data = f.read(length)
            footer = f.read(4)
            if len(data) < length or len(footer) < 4:
                raise ReplayError(f"{where}: truncated ({len(data)} of {length} data bytes)")
            if masked_crc(data) != struct.unpack("<I", footer)[0]:
                raise ReplayError(f"{where}: the data's checksum does not match (corrupted)")
            yield data
            index += 1
