"""``smarts.npz``: what it writes ``numpy.load`` reads, what numpy writes it reads, bit for bit, and
a broken file is an error, never wrong arrays."""

import io
import zipfile

import numpy as np
import pytest

from smarts.npz import read_npz, write_npz

ARRAYS = {
    "metadata": np.array('{"format": "x", "n": 3}'),
    "agents/0/x": np.linspace(-3.5, 9.25, 41),
    "agents/0/flags": np.array([True, False, True]),
    "agents/0/lane": np.arange(-1, 7, dtype=np.int16),
    "scene/xy": np.arange(24, dtype=np.float32).reshape(4, 6),
    "scene/fortran": np.asfortranarray(np.arange(12, dtype=np.int64).reshape(3, 4)),
    "scene/ids": np.array(["car_1", "lead", "ped"]),
    "scene/empty": np.zeros((0, 3)),
    "nan": np.array([np.nan, np.inf, -0.0]),
    "structured": np.array([(1, 2.5)], dtype=[("a", "<i4"), ("b", "<f8")]),
}


def _same(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for key in a:
        assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
        assert a[key].tobytes(order="A") == b[key].tobytes(order="A"), key
        assert a[key].flags.f_contiguous == b[key].flags.f_contiguous, key


def test_numpy_reads_what_is_written_and_it_reads_what_numpy_writes(tmp_path):
    ours = tmp_path / "ours.npz"
    with open(ours, "wb") as fh:
        write_npz(fh, ARRAYS)
    with np.load(ours, allow_pickle=False) as npz:
        _same(ARRAYS, {k: npz[k] for k in npz.files})
    theirs = tmp_path / "theirs.npz"
    np.savez_compressed(theirs, **ARRAYS)
    read = read_npz(theirs)
    _same(ARRAYS, read)
    _same(ARRAYS, read_npz(ours))
    read["agents/0/x"][0] = 1.0  # writable, as numpy.load gives them


def test_broken_files_are_errors(tmp_path):
    good = io.BytesIO()
    write_npz(good, {"x": np.arange(100.0)})
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.getvalue()[:-40])
    with pytest.raises((zipfile.BadZipFile, ValueError, OSError, EOFError)):
        read_npz(truncated)
    short = tmp_path / "short_member.npz"
    with zipfile.ZipFile(short, "w") as zf:
        buf = io.BytesIO()
        np.lib.format.write_array(buf, np.arange(10.0))
        zf.writestr("x.npy", buf.getvalue()[:-8])
    with pytest.raises(ValueError, match="header says"):
        read_npz(short)
    pickled = tmp_path / "objects.npz"
    np.savez(pickled, x=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError, match="allow_pickle"):
        read_npz(pickled)
    not_array = tmp_path / "text.npz"
    with zipfile.ZipFile(not_array, "w") as zf:
        zf.writestr("x.npy", b"hello")
    with pytest.raises(ValueError, match="not a numpy array"):
        read_npz(not_array)


def test_the_same_arrays_give_the_same_bytes_and_zipfile_checks_them():
    first, second = io.BytesIO(), io.BytesIO()
    write_npz(first, ARRAYS)
    write_npz(second, {k: v.copy(order="K") for k, v in ARRAYS.items()})
    assert first.getvalue() == second.getvalue()  # no clock in the archive
    with zipfile.ZipFile(first) as zf:
        assert zf.testzip() is None  # every member's CRC-32 as recorded
        assert [i.filename for i in zf.infolist()] == [f"{k}.npy" for k in ARRAYS]


def test_a_damaged_member_is_an_error_not_wrong_arrays(tmp_path):
    good = io.BytesIO()
    write_npz(good, {"x": np.arange(1000.0), "y": np.ones(50)})
    data = bytearray(good.getvalue())
    for at in (60, 200, 400):  # inside the first member's compressed data
        damaged = tmp_path / f"damaged_{at}.npz"
        data_at = bytearray(data)
        data_at[at] ^= 0xFF
        damaged.write_bytes(bytes(data_at))
        with pytest.raises((zipfile.BadZipFile, ValueError)):
            read_npz(damaged)
