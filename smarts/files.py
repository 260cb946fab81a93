"""How the project's outputs reach the disk: one atomic write, and numbered run folders.

Every report, result table, episode log, recording and cache entry is written by
:func:`atomic_write` (or its ``_bytes``/``_text`` forms): the data goes to a temporary name in the
destination folder, is flushed to disk, takes the permissions a plain ``open()`` would have given
it (``0666`` less the process umask: ``0644`` under the usual ``022``, so colleagues on a shared
machine can read a benchmark run), and is renamed over the final name. A reader, or a run killed
half-way, sees the old file or the new one, never half of one; a killed writer leaves only a
temporary name (``.tmp-<name>-...``, see :func:`partial_writes`).

Why not ``tempfile.mkstemp`` alone: it creates its files ``0600`` whatever the umask, which made
every atomically written output unreadable to anyone but its owner.

Runs that must never overwrite each other (training runs, benchmark runs) go to the next numbered
folder under a root (:func:`next_numbered`: ``001``, ``002``, ...), and ``<root>/latest`` points to
the newest (:func:`point_latest`).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

TEMP_PREFIX = ".tmp-"
"""Name prefix of files and folders still being written; never read as outputs."""

_umask_lock = threading.Lock()


def process_umask() -> int:
    """The process's umask, read without changing it where the system says it (Linux's
    ``/proc/self/status``); elsewhere set and restored under a lock."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    with _umask_lock:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def default_file_mode() -> int:
    """The mode ``open(path, "w")`` gives a new file: ``0666`` less the umask."""
    return 0o666 & ~process_umask()


def fsync_dir(path: Path) -> None:
    """Make a rename in ``path`` durable (best effort: not every platform can open a folder)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def partial_writes(path: str | os.PathLike) -> list[Path]:
    """The temporary files of ``path`` that killed writers left behind in its folder."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    return sorted(path.parent.glob(f"{TEMP_PREFIX}{path.name}-*"))


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, *, mode: int | None = None, durable: bool = True) -> Iterator[BinaryIO]:
    """A binary file to write ``path``'s new contents into; on a clean exit it is flushed, given
    ``mode`` (default :func:`default_file_mode`) and renamed over ``path``. On an exception the
    temporary file is removed and ``path`` is left as it was. ``durable``: fsync the file and the
    folder (a report survives a power cut; off for scratch files)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{path.name}-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fchmod(fh.fileno(), default_file_mode() if mode is None else mode)
            if durable:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if durable:
        fsync_dir(path.parent)


def atomic_write_bytes(
    path: str | os.PathLike, data: bytes | bytearray | memoryview, *, mode: int | None = None
) -> Path:
    """Write ``data`` to ``path`` with :func:`atomic_write`; returns the path."""
    with atomic_write(path, mode=mode) as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, *, mode: int | None = None) -> Path:
    """Write ``text`` (UTF-8, line endings as given) to ``path`` with :func:`atomic_write`."""
    return atomic_write_bytes(path, text.encode("utf-8"), mode=mode)


# ---------------------------------------------------------------------------------- run folders
def next_numbered(root: str | os.PathLike) -> Path:
    """The next numbered folder under ``root`` (``001`` when there is none, else one more than the
    highest). Nothing is created: the caller makes it once its checks have passed."""
    root = Path(root)
    taken = [int(p.name) for p in root.iterdir() if p.name.isdigit()] if root.is_dir() else []
    return root / f"{max(taken, default=0) + 1:03d}"


def point_latest(root: str | os.PathLike, folder: str | os.PathLike) -> None:
    """``root/latest`` -> ``folder`` (a relative symlink, replaced atomically; a text file
    ``latest.txt`` holding the folder's name where symlinks are not allowed). A real folder called
    ``latest`` is the user's and is left alone."""
    root, folder = Path(root), Path(folder)
    link = root / "latest"
    temporary = root / f"{TEMP_PREFIX}latest-{folder.name}"
    try:
        temporary.unlink(missing_ok=True)
        temporary.symlink_to(folder.name, target_is_directory=True)
        if link.is_dir() and not link.is_symlink():
            temporary.unlink()
            return
        temporary.replace(link)
    except OSError:
        temporary.unlink(missing_ok=True)
        if not link.is_symlink() and link.is_dir():
            return
        atomic_write_text(root / "latest.txt", folder.name + "\n")


def latest(root: str | os.PathLike) -> Path | None:
    """The folder ``root/latest`` points to (the symlink, or ``latest.txt``); None when none."""
    root = Path(root)
    link = root / "latest"
    if link.is_symlink() or link.is_dir():
        return link.resolve() if link.exists() else None
    text = root / "latest.txt"
    if text.is_file():
        name = text.read_text().strip()
        if name and (root / name).is_dir():
            return root / name
    return None
