"""Load a road map from a file, compiling it at most once per content.

Compiling a large network takes seconds; the compiled arrays are cached on disk keyed by the
SHA-256 of the source bytes (so an edited file is recompiled and a renamed one is not) and kept in
memory for the life of the process.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path

from smarts import cache
from smarts.cache import cache_home
from smarts.maps.errors import MapError
from smarts.maps.opendrive import (
    IGNORED_ERRORS_NAME,
    ConversionError,
    convert_opendrive,
    netconvert_identity,
    warn_ignored_errors,
)
from smarts.maps.road_map import RoadMap
from smarts.maps.sumo_net import compile_sumo_net, read_map_bytes

FORMAT_VERSION = 5
"""Version of the compiled arrays; bump it whenever compilation output changes meaning
(3: the file records the SHA-256 of its arrays; 4: SUMO's lane lengths)."""

_SUFFIXES = (".net.xml", ".xodr")
_loaded: dict[tuple[str, str], RoadMap] = {}
_log = logging.getLogger(__name__)


def default_cache_dir() -> Path:
    """``<cache home>/maps`` (see ``smarts.cache``)."""
    return cache_home() / "maps"


def load_map(path: str | Path, cache_dir: Path | None = None) -> RoadMap:
    """Compiled :class:`RoadMap` for a ``.net.xml`` or ``.xodr`` file (cached by content hash).

    A cached file that is unreadable, partial or fails its recorded SHA-256 is compiled again and
    replaced; an unwritable cache folder falls back to this process's temporary cache (one warning,
    see ``smarts.cache``).
    """
    path = Path(path)
    name = _checked_name(path)
    content_hash = hashlib.sha256(read_map_bytes(path)).hexdigest()
    key = f"{content_hash}-v{FORMAT_VERSION}"
    # Kept per path as well as content: a map's ``source`` is the file it was loaded from, which
    # SUMO reads later, so a copy elsewhere (since deleted) must not stand in for this one.
    memo_key = (key, str(path))
    road_map = _loaded.get(memo_key)
    if road_map is not None:
        return road_map
    if name.endswith(".xodr"):  # built from a network netconvert made with --ignore-errors?
        for folder in cache.candidates(Path(cache_dir) if cache_dir is not None else default_cache_dir()):
            _warn_if_converted_leniently(path, folder / f"{content_hash}-net")

    cache_folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    for folder in cache.candidates(cache_folder):
        cached_file = folder / f"{key}.npz"
        if not cached_file.is_file():
            continue
        try:
            road_map = RoadMap.load(cached_file)
            road_map.source = str(path)  # compiled from a file of the same content, maybe elsewhere
            break
        except MapError as err:  # a truncated or damaged entry: compile again and replace it
            _log.warning("rebuilding the cached compiled map: %s", err)
    if road_map is None:
        road_map = _compile(path, name, cache_folder, content_hash)
        folder = cache.writable_dir(cache_folder)
        try:
            road_map.save(folder / f"{key}.npz")
        except OSError as err:
            try:
                road_map.save(cache.fallback_for(cache_folder, err) / f"{key}.npz")
            except OSError:
                pass  # not even the temporary cache: the map is still kept in memory
    _loaded[memo_key] = road_map
    return road_map


def sumo_net_path(path: str | Path, cache_dir: Path | None = None) -> Path:
    """The SUMO network for a map file: the file itself for ``.net.xml``, or the (cached)
    netconvert output for ``.xodr``, so SUMO traffic can run on either format.

    A converted network is cached as a folder ``<sha256 of the .xodr>-net`` holding the
    ``.net.xml`` and a ``SHA256SUMS`` manifest; it is built privately and renamed into place, and
    rebuilt when its files no longer match the manifest. A network netconvert could only build
    with ``--ignore-errors`` also holds the list of what it ignored, repeated as a warning on
    every load.

    A file netconvert rejects altogether is remembered as ``<sha256>-net.failed`` (netconvert's
    message and which netconvert gave it): later loads of the same content fail at once with the
    same message instead of converting again; a changed file or another netconvert tries again.
    """
    path = Path(path)
    if _checked_name(path).endswith(".net.xml"):
        if not path.is_file():
            raise MapError(f"{path}: map file not found")
        return path
    content_hash = hashlib.sha256(read_map_bytes(path)).hexdigest()
    cache_folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    entry_name = f"{content_hash}-net"
    net_name = f"{path.name[: -len('.xodr')]}.net.xml"
    failed_name = f"{entry_name}.failed"
    identity = netconvert_identity()
    for folder in cache.candidates(cache_folder):
        problem = cache.check_manifest(folder / entry_name, [net_name])
        if problem is None:
            _warn_if_converted_leniently(path, folder / entry_name)
            return folder / entry_name / net_name
        if problem != "missing":
            _log.warning("rebuilding the cached network of %s in %s: %s", path, folder, problem)
    for folder in cache.candidates(cache_folder):
        detail = _cached_failure(folder / failed_name, identity)
        if detail is not None:
            raise ConversionError(path, detail)
    folder = cache.writable_dir(cache_folder)
    try:
        build = cache.new_build_dir(folder, "xodr")
    except OSError as err:
        folder = cache.fallback_for(cache_folder, err)
        build = cache.new_build_dir(folder, "xodr")
    try:
        try:
            convert_opendrive(path, build)
        except ConversionError as err:
            _remember_failure(folder / failed_name, identity, err.detail)
            raise
        names = [net_name] + ([IGNORED_ERRORS_NAME] if (build / IGNORED_ERRORS_NAME).is_file() else [])
        cache.write_manifest(build, names)
        final = cache.publish_dir(build, folder / entry_name, lambda d: cache.check_manifest(d, [net_name]) is None)
    finally:
        if build.exists():
            shutil.rmtree(build, ignore_errors=True)
    _warned_lenient.add((str(path), str(final)))  # convert_opendrive has just warned
    return final / net_name


_warned_lenient: set[tuple[str, str]] = set()


def _warn_if_converted_leniently(path: Path, entry: Path) -> None:
    """Repeat (once per process and file) the warning of a conversion with ``--ignore-errors``."""
    ignored = entry / IGNORED_ERRORS_NAME
    if not ignored.is_file() or (str(path), str(entry)) in _warned_lenient:
        return
    _warned_lenient.add((str(path), str(entry)))
    try:
        lines = ignored.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        lines = []
    warn_ignored_errors(path, [line for line in lines if line.strip()])


def _cached_failure(record: Path, identity: str) -> str | None:
    """netconvert's message from a failure record made by this netconvert, else None."""
    try:
        data = json.loads(record.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None  # none, unreadable or partial: convert (and record) again
    if not isinstance(data, dict) or data.get("netconvert") != identity:
        return None
    detail = data.get("error")
    return detail if isinstance(detail, str) and detail else None


def _remember_failure(record: Path, identity: str, detail: str) -> None:
    data = json.dumps({"netconvert": identity, "error": detail}, indent=1).encode()
    try:
        cache.atomic_write_bytes(record, data)
    except OSError as err:
        _log.warning("cannot record the failed conversion in %s: %s", record, err)


def _compile(path: Path, name: str, cache: Path, content_hash: str) -> RoadMap:
    if name.endswith(".net.xml"):
        return compile_sumo_net(path)
    net = sumo_net_path(path, cache)
    try:
        road_map = compile_sumo_net(net)
    except MapError as err:
        raise MapError(f"{path}: the network converted from it is unusable: {err}") from None
    # Record the OpenDRIVE file (not the intermediate network) as the map's source.
    road_map.source = str(path)
    road_map.content_hash = content_hash
    return road_map


def _checked_name(path: Path) -> str:
    """Lower-cased file name, after checking the suffix names a supported format."""
    name = path.name.lower()
    if not name.endswith(_SUFFIXES):
        raise MapError(f"{path}: unknown map format; expected a file ending in {' or '.join(_SUFFIXES)}")
    return name


def clear_memory_cache() -> None:
    """Forget maps loaded in this process (the on-disk cache is kept)."""
    _loaded.clear()
