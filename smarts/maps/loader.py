"""Load a road map from a file, compiling it at most once per content.

Compiling a large network takes seconds; the compiled arrays are cached on disk keyed by the
SHA-256 of the source bytes (so an edited file is recompiled and a renamed one is not) and kept in
memory for the life of the process.
"""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path

from smarts.cache import cache_home
from smarts.maps.errors import MapError
from smarts.maps.opendrive import convert_opendrive
from smarts.maps.road_map import RoadMap
from smarts.maps.sumo_net import compile_sumo_net, read_map_bytes

FORMAT_VERSION = 2
"""Version of the compiled arrays; bump it whenever compilation output changes meaning."""

_SUFFIXES = (".net.xml", ".xodr")
_loaded: dict[str, RoadMap] = {}


def default_cache_dir() -> Path:
    """``<cache home>/maps`` (see ``smarts.cache``)."""
    return cache_home() / "maps"


def load_map(path: str | Path, cache_dir: Path | None = None) -> RoadMap:
    """Compiled :class:`RoadMap` for a ``.net.xml`` or ``.xodr`` file (cached by content hash)."""
    path = Path(path)
    name = _checked_name(path)
    content_hash = hashlib.sha256(read_map_bytes(path)).hexdigest()
    key = f"{content_hash}-v{FORMAT_VERSION}"
    road_map = _loaded.get(key)
    if road_map is not None:
        return road_map

    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cached_file = cache / f"{key}.npz"
    if cached_file.is_file():
        try:
            road_map = RoadMap.load(cached_file)
        except Exception:  # a truncated or foreign file: recompile and overwrite it
            road_map = None
    if road_map is None:
        road_map = _compile(path, name, cache, content_hash)
        try:
            cache.mkdir(parents=True, exist_ok=True)
            road_map.save(cached_file)
        except OSError:
            pass  # a read-only cache only costs a recompile next time
    _loaded[key] = road_map
    return road_map


def sumo_net_path(path: str | Path, cache_dir: Path | None = None) -> Path:
    """The SUMO network for a map file: the file itself for ``.net.xml``, or the (cached)
    netconvert output for ``.xodr``, so SUMO traffic can run on either format."""
    path = Path(path)
    if _checked_name(path).endswith(".net.xml"):
        if not path.is_file():
            raise MapError(f"{path}: map file not found")
        return path
    content_hash = hashlib.sha256(read_map_bytes(path)).hexdigest()
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    out_dir = cache / f"{content_hash}-net"
    name = path.name[: -len(".xodr")]
    existing = out_dir / f"{name}.net.xml"
    if existing.is_file():
        return existing
    try:
        return convert_opendrive(path, out_dir)
    except OSError:
        return convert_opendrive(path, Path(tempfile.mkdtemp(prefix="smarts-xodr-")))


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
        raise MapError(
            f"{path}: unknown map format; expected a file ending in {' or '.join(_SUFFIXES)}"
        )
    return name


def clear_memory_cache() -> None:
    """Forget maps loaded in this process (the on-disk cache is kept)."""
    _loaded.clear()
