"""The cache's building blocks: atomic writes, checksummed folder entries, stale left-overs and
the temporary cache used when the cache folder cannot be written."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from smarts import cache
from tests.builders import PERMISSIONS_SKIP


def unwritable_dir(tmp_path: Path) -> Path:
    """A cache folder nobody can create: it lies under a regular file (fails even for root)."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a regular file")
    return blocker / "cache"


def test_atomic_write_replaces_whole_files_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "entry.bin"
    cache.atomic_write_bytes(target, b"first")
    cache.atomic_write_bytes(target, b"second version")
    assert target.read_bytes() == b"second version"
    assert os.listdir(tmp_path) == ["entry.bin"]


def test_atomic_write_interrupted_before_the_rename_keeps_the_old_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "entry.bin"
    cache.atomic_write_bytes(target, b"old")

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(cache.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        cache.atomic_write_bytes(target, b"new, never complete")
    assert target.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["entry.bin"]


def test_manifest_detects_truncated_changed_and_missing_files(tmp_path: Path) -> None:
    entry = tmp_path / "entry"
    entry.mkdir()
    (entry / "a.net.xml").write_text("<net>" + "x" * 1000 + "</net>")
    (entry / "b.xml").write_text("<b/>")
    assert cache.check_manifest(entry, ["a.net.xml"]) == "no readable SHA256SUMS"
    cache.write_manifest(entry, ["a.net.xml", "b.xml"])
    assert cache.check_manifest(entry, ["a.net.xml"]) is None
    assert "c.xml" in cache.check_manifest(entry, ["c.xml"])

    data = (entry / "a.net.xml").read_bytes()
    (entry / "a.net.xml").write_bytes(data[: len(data) // 2])
    assert "a.net.xml does not match" in cache.check_manifest(entry, ["a.net.xml"])
    (entry / "a.net.xml").write_bytes(data)
    (entry / "b.xml").unlink()
    assert cache.check_manifest(entry) == "b.xml is missing"
    (entry / cache.MANIFEST).write_text("garbage\n")
    assert "malformed" in cache.check_manifest(entry)
    assert cache.check_manifest(tmp_path / "absent") == "missing"


def test_publish_replaces_a_broken_entry_and_keeps_a_valid_one(tmp_path: Path) -> None:
    def valid(d: Path) -> bool:
        return cache.check_manifest(d, ["f"]) is None

    def built(text: str) -> Path:
        build = cache.new_build_dir(tmp_path, "build")
        (build / "f").write_text(text)
        cache.write_manifest(build, ["f"])
        return build

    final = tmp_path / "entry"
    final.mkdir()
    (final / "f").write_text("half")  # no manifest: what a killed copy would leave
    assert cache.publish_dir(built("one"), final, valid) == final
    assert (final / "f").read_text() == "one"

    late = built("two")  # a second builder finishing after the first: its build is not used
    assert cache.publish_dir(late, final, valid) == final
    assert (final / "f").read_text() == "one" and late.is_dir()
    assert sorted(os.listdir(tmp_path)) == sorted(["entry", late.name])


def test_stale_temporaries_are_swept_and_fresh_ones_kept(tmp_path: Path) -> None:
    old_dir = tmp_path / f"{cache.TEMP_PREFIX}build-x-old"
    old_dir.mkdir()
    (old_dir / "part.xml").write_text("<")
    old_file = tmp_path / f"{cache.TEMP_PREFIX}map.npz-old"
    old_file.write_bytes(b"PK")
    fresh = tmp_path / f"{cache.TEMP_PREFIX}build-y-now"
    fresh.mkdir()
    entry = tmp_path / "kept-entry"
    entry.mkdir()
    long_ago = time.time() - 2 * cache.STALE_AFTER_S
    for p in (old_dir, old_file, entry):
        os.utime(p, (long_ago, long_ago))
    cache.sweep_stale(tmp_path)
    assert sorted(os.listdir(tmp_path)) == sorted([fresh.name, entry.name])


def test_unwritable_folder_falls_back_once_with_one_warning(tmp_path: Path, fresh_fallback: None) -> None:
    wanted = unwritable_dir(tmp_path)
    with pytest.warns(cache.UnwritableCacheWarning) as record:
        got = cache.writable_dir(wanted / "netconvert", home=wanted)
        again = cache.writable_dir(wanted / "maps", home=wanted)
    assert len(record) == 1
    message = str(record[0].message)
    assert str(wanted / "netconvert") in message and "SMARTS_CACHE_DIR" in message
    fallback = cache.fallback_home(create=False)
    assert fallback is not None and fallback.name.startswith(cache.FALLBACK_PREFIX)
    assert got == fallback / "netconvert" and got.is_dir()
    assert again == fallback / "maps" and again.is_dir()
    assert cache.candidates(wanted / "maps") == [wanted / "maps", fallback / "maps"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cache.writable_dir(wanted / "maps", home=wanted) == again  # no second warning
        assert cache.writable_dir(tmp_path / "fine") == tmp_path / "fine"


@PERMISSIONS_SKIP
def test_read_only_folder_falls_back(tmp_path: Path, fresh_fallback: None) -> None:
    read_only = tmp_path / "ro"
    read_only.mkdir()
    read_only.chmod(0o500)
    try:
        with pytest.warns(cache.UnwritableCacheWarning, match="SMARTS_CACHE_DIR") as record:
            got = cache.writable_dir(read_only / "maps", home=read_only)
        assert len(record) == 1 and str(read_only / "maps") in str(record[0].message)
        assert got.parent == cache.fallback_home(create=False)
    finally:
        read_only.chmod(0o700)


def test_temporary_cache_is_removed_when_the_process_exits(tmp_path: Path) -> None:
    code = (
        "import sys, warnings; warnings.simplefilter('ignore')\n"
        "from pathlib import Path\n"
        "from smarts import cache\n"
        "d = cache.writable_dir(Path(sys.argv[1]) / 'maps')\n"
        "(d / 'entry').write_text('x')\n"
        "print(d.parent)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, str(unwritable_dir(tmp_path))],
        capture_output=True,
        text=True,
        check=True,
    )
    fallback = Path(done.stdout.strip())
    assert fallback.name.startswith(cache.FALLBACK_PREFIX)
    assert not fallback.exists()
