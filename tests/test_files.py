"""The project's one atomic write (``smarts.files``): outputs are readable by group and others as a
plain ``open()`` would make them (0644 under umask 022), a failed write leaves the old file and no
temporary name, and numbered run folders with their ``latest`` pointer."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from smarts import files


@pytest.fixture
def umask_022():
    before = os.umask(0o022)
    yield
    os.umask(before)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_atomic_writes_take_the_umask_mode_not_0600(tmp_path, umask_022):
    assert files.process_umask() == 0o022
    assert mode(files.atomic_write_text(tmp_path / "a.md", "# hi\n")) == 0o644
    os.umask(0o027)
    assert mode(files.atomic_write_bytes(tmp_path / "b.bin", b"x")) == 0o640
    assert (tmp_path / "a.md").read_text() == "# hi\n"


def test_episode_logs_recordings_and_cache_entries_are_readable_by_others(tmp_path, umask_022):
    from smarts import cache
    from smarts.benchmark.metrics import write_episode
    from smarts.benchmark.metrics.synthetic import make_episode, make_trace

    log = write_episode(make_episode({"a": make_trace(20)}), tmp_path / "log.npz")
    cache.atomic_write_bytes(tmp_path / "entry", b"data")
    assert mode(log) == 0o644 and mode(tmp_path / "entry") == 0o644


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary_name(tmp_path):
    path = files.atomic_write_text(tmp_path / "r.json", "old")
    with pytest.raises(RuntimeError), files.atomic_write(path) as fh:
        fh.write(b"half")
        raise RuntimeError("killed")
    assert path.read_text() == "old" and files.partial_writes(path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_numbered_folders_and_latest(tmp_path):
    root = tmp_path / "runs"
    first = files.next_numbered(root)
    assert first == root / "001" and not root.exists()  # nothing made before the checks
    first.mkdir(parents=True)
    files.point_latest(root, first)
    second = files.next_numbered(root)
    second.mkdir()
    files.point_latest(root, second)
    assert second.name == "002" and files.latest(root) == second.resolve()
    assert os.readlink(root / "latest") == "002"  # relative: the folder can move
    assert files.latest(tmp_path / "none") is None


def test_a_real_latest_folder_is_left_alone(tmp_path):
    (tmp_path / "latest").mkdir()
    (tmp_path / "latest" / "mine.txt").write_text("keep")
    (tmp_path / "001").mkdir()
    files.point_latest(tmp_path, tmp_path / "001")
    assert (tmp_path / "latest" / "mine.txt").read_text() == "keep"
    assert np.array_equal(sorted(p.name for p in tmp_path.iterdir()), ["001", "latest"])
