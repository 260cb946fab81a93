"""Where generated files (netconvert output, compiled maps) are cached, and how entries are written.

Every entry is either one file written atomically (:func:`atomic_write_bytes`, the project's one
atomic write in ``smarts.files``: a temporary file in the same folder, flushed to disk, then
renamed over the final name) or a folder built privately and
renamed into place whole (:func:`publish_dir`) with a ``SHA256SUMS`` manifest of its files
(:func:`write_manifest`, checked by :func:`check_manifest`). A process killed half-way therefore
leaves only a temporary name behind, never an entry that looks complete; an entry damaged later
(a truncated copy, a full disk, an edit by hand) fails its hash check and is rebuilt.

When the cache folder cannot be written (read-only, owned by someone else, a path through a
regular file), :func:`writable_dir` falls back to one temporary cache folder for this process
(``smarts-cache-*`` in the system temporary folder, removed at exit) and warns once, naming the
folder that could not be written and ``SMARTS_CACHE_DIR``.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import logging
import os
import shutil
import tempfile
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path

from smarts import files
from smarts.files import fsync_dir

ENV_VAR = "SMARTS_CACHE_DIR"
FALLBACK_PREFIX = "smarts-cache-"
"""Name prefix of the per-process temporary cache used when the cache folder is unwritable."""
MANIFEST = "SHA256SUMS"
"""File in a folder entry listing ``<sha256>  <name>`` for each of its files (``sha256sum -c``)."""
TEMP_PREFIX = files.TEMP_PREFIX
"""Name prefix of files and folders still being written; never read as entries."""
STALE_AFTER_S = 24 * 3600.0
"""Temporary names older than this are left-overs of killed processes and are swept."""

logger = logging.getLogger(__name__)

_lock = threading.Lock()
_fallback: Path | None = None
_fallback_pid: int | None = None
_warned: set[str] = set()


class UnwritableCacheWarning(UserWarning):
    """The cache folder cannot be written; a temporary one is used for this process."""


def cache_home() -> Path:
    """``$SMARTS_CACHE_DIR`` if set, else ``~/.cache/smarts``."""
    env = os.environ.get(ENV_VAR)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "smarts"


# ------------------------------------------------------------------ unwritable cache folders
def fallback_home(create: bool = True) -> Path | None:
    """This process's temporary cache folder (created on first need, removed at exit)."""
    global _fallback, _fallback_pid
    with _lock:
        if _fallback is None and create:
            _fallback = Path(tempfile.mkdtemp(prefix=FALLBACK_PREFIX))
            _fallback_pid = os.getpid()
            atexit.register(_remove_fallback)
        return _fallback


def _remove_fallback() -> None:
    # A forked child shares the folder with its parent; only the creator removes it.
    if _fallback is not None and os.getpid() == _fallback_pid:
        shutil.rmtree(_fallback, ignore_errors=True)


def candidates(path: Path) -> list[Path]:
    """Where an entry of the cache folder ``path`` may be: ``path`` itself and, once this process
    had to fall back, the same-named folder of its temporary cache."""
    found = [Path(path)]
    fallback = fallback_home(create=False)
    if fallback is not None:
        found.append(fallback / Path(path).name)
    return found


def writable_dir(path: Path, home: Path | None = None) -> Path:
    """``path`` (created if missing) when files can be written in it, else ``<temporary cache>/<name>``.

    ``home`` is the cache folder ``path`` belongs to (default: its parent): the warning about an
    unwritable cache is given once per home, so its sub-folders (built maps, compiled maps) do not
    each repeat it.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=TEMP_PREFIX + "probe-", dir=path)
        os.close(fd)
        os.unlink(probe)
        return path
    except OSError as err:
        return fallback_for(path, err, home)


def fallback_for(path: Path, err: OSError, home: Path | None = None) -> Path:
    """The temporary cache's folder standing in for ``path``, which could not be written (``err``);
    warns once per cache home."""
    path = Path(path)
    fallback = fallback_home() / path.name
    fallback.mkdir(parents=True, exist_ok=True)
    key = str(Path(home) if home is not None else path.parent)
    with _lock:
        first = key not in _warned
        _warned.add(key)
    reason = err.strerror or type(err).__name__
    if first:
        warnings.warn(
            f"cannot write to the cache directory {path} ({reason}); using {fallback_home()} for "
            f"this process, so maps are rebuilt on every run. Set {ENV_VAR} to a writable "
            f"directory to keep them.",
            UnwritableCacheWarning,
            stacklevel=3,
        )
    else:
        logger.debug("cache directory %s is not writable (%s); using %s", path, reason, fallback)
    return fallback


# ------------------------------------------------------------------ atomic writes and checks
def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so readers see the old file, no file, or all of ``data``
    (``smarts.files.atomic_write_bytes``, the project's one atomic write: readable by others as
    a plain ``open()`` would make it)."""
    files.atomic_write_bytes(path, data)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(folder: Path, names: Iterable[str]) -> None:
    """Flush ``names`` (files in ``folder``) to disk and record their SHA-256 in ``SHA256SUMS``."""
    folder = Path(folder)
    lines = []
    for name in sorted(names):
        with open(folder / name, "rb") as f:
            os.fsync(f.fileno())
        lines.append(f"{sha256_file(folder / name)}  {name}\n")
    atomic_write_bytes(folder / MANIFEST, "".join(lines).encode())


def check_manifest(folder: Path, required: Iterable[str] = ()) -> str | None:
    """Why the folder entry is unusable (missing, no manifest, a file missing or changed), or None."""
    folder = Path(folder)
    if not folder.is_dir():
        return "missing"
    try:
        text = (folder / MANIFEST).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return f"no readable {MANIFEST}"
    listed: dict[str, str] = {}
    for line in text.splitlines():
        digest, sep, name = line.partition("  ")
        if not sep or len(digest) != 64 or not name or "/" in name or name.startswith(".."):
            return f"{MANIFEST} is malformed"
        listed[name] = digest
    missing = [n for n in required if n not in listed]
    if not listed or missing:
        return f"{MANIFEST} does not list {', '.join(missing) or 'any file'}"
    for name, digest in listed.items():
        try:
            actual = sha256_file(folder / name)
        except OSError:
            return f"{name} is missing"
        if actual != digest:
            return f"{name} does not match its recorded SHA-256 (truncated or changed)"
    return None


def new_build_dir(root: Path, label: str) -> Path:
    """A private folder in ``root`` to build an entry in before :func:`publish_dir`."""
    sweep_stale(root)
    return Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{label}-", dir=root))


def publish_dir(build: Path, final: Path, is_valid: Callable[[Path], bool]) -> Path:
    """Rename the finished folder ``build`` to ``final`` and return ``final``.

    An entry already at ``final`` is kept when ``is_valid`` accepts it (another process finished
    first: ``build`` is then left for the caller to remove) and moved aside and deleted otherwise.
    """
    build, final = Path(build), Path(final)
    fsync_dir(build)
    for _ in range(5):
        try:
            os.rename(build, final)
        except OSError:
            if is_valid(final):
                return final
            aside = final.with_name(f"{TEMP_PREFIX}broken-{final.name}-{uuid.uuid4().hex[:8]}")
            try:
                os.rename(final, aside)
            except FileNotFoundError:
                continue  # removed by another process meanwhile: try again
            if aside.is_dir():
                shutil.rmtree(aside, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    aside.unlink()
            continue
        fsync_dir(final.parent)
        return final
    raise OSError(f"could not put the cache entry {final} in place")


def sweep_stale(root: Path, max_age_s: float = STALE_AFTER_S) -> None:
    """Remove temporary names in ``root`` left by processes killed more than ``max_age_s`` ago."""
    now = time.time()
    try:
        entries = list(os.scandir(root))
    except OSError:
        return
    for entry in entries:
        if not entry.name.startswith(TEMP_PREFIX):
            continue
        try:
            if now - entry.stat(follow_symlinks=False).st_mtime < max_age_s:
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                os.unlink(entry.path)
        except OSError:
            pass
