"""Loading maps by file type, with the on-disk and in-process caches."""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from smarts.maps import FORMAT_VERSION, MapError, load_map, project, sumo_net_path
from smarts.maps.loader import clear_memory_cache
from smarts.maps.road_map import RoadMap


def assert_same_map(a: RoadMap, b: RoadMap) -> None:
    for f in fields(RoadMap):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "junction_shapes":
            assert len(x) == len(y)
            for s, t in zip(x, y):
                np.testing.assert_array_equal(s, t)
        elif isinstance(x, np.ndarray):
            assert x.dtype == np.asarray(y).dtype, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


def test_disk_cache_round_trip(tmp_path: Path, cross_net: Path) -> None:
    net = tmp_path / "cross.net.xml"
    shutil.copy(cross_net, net)
    cache = tmp_path / "cache"
    first = load_map(net, cache_dir=cache)
    digest = hashlib.sha256(net.read_bytes()).hexdigest()
    assert first.content_hash == digest
    cached = cache / f"{digest}-v{FORMAT_VERSION}.npz"
    assert cached.is_file()

    assert load_map(net, cache_dir=cache) is first  # in-process cache
    clear_memory_cache()
    again = load_map(str(net), cache_dir=cache)  # from the .npz this time
    assert again is not first
    assert_same_map(first, again)
    assert again.lane("WC_0") == first.lane("WC_0")
    p = project(again, np.array([[50.0, -1.0]]), np.zeros(1))
    assert again.lane_ids[p.lane[0]] == "CE_0"


def test_changed_file_gets_a_new_hash(tmp_path: Path, straight_net: Path) -> None:
    net = tmp_path / "road.net.xml"
    text = straight_net.read_text()
    net.write_text(text)
    before = load_map(net, cache_dir=tmp_path / "cache")
    net.write_text(text.replace('speed="20.00"', 'speed="25.00"'))
    after = load_map(net, cache_dir=tmp_path / "cache")
    assert after.content_hash != before.content_hash
    np.testing.assert_allclose(before.lane_speed_limit, 20.0)
    np.testing.assert_allclose(after.lane_speed_limit, 25.0)
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 2


def test_corrupt_cache_file_is_recompiled(tmp_path: Path, straight_net: Path) -> None:
    cache = tmp_path / "cache"
    cache.mkdir()
    digest = hashlib.sha256(straight_net.read_bytes()).hexdigest()
    (cache / f"{digest}-v{FORMAT_VERSION}.npz").write_bytes(b"not an npz")
    clear_memory_cache()
    m = load_map(straight_net, cache_dir=cache)
    assert m.lane_ids == ["AB_1", "AB_2"]
    assert RoadMap.load(cache / f"{digest}-v{FORMAT_VERSION}.npz").lane_ids == m.lane_ids


def test_default_cache_dir_comes_from_the_environment(
    tmp_path: Path, straight_net: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(tmp_path / "env-cache"))
    clear_memory_cache()
    load_map(straight_net)
    assert len(list((tmp_path / "env-cache" / "maps").glob("*.npz"))) == 1


def test_unknown_suffix_and_missing_file_name_the_file(tmp_path: Path) -> None:
    odd = tmp_path / "map.osm"
    odd.write_text("<osm/>")
    with pytest.raises(MapError, match=r"map.osm.*\.net\.xml or \.xodr"):
        load_map(odd, cache_dir=tmp_path)
    with pytest.raises(MapError, match="absent.net.xml.*not found"):
        load_map(tmp_path / "absent.net.xml", cache_dir=tmp_path)
    with pytest.raises(MapError, match="absent.xodr.*not found"):
        load_map(tmp_path / "absent.xodr", cache_dir=tmp_path)


def test_malformed_file_through_the_loader(tmp_path: Path) -> None:
    bad = tmp_path / "broken.net.xml"
    bad.write_text("<net><edge id='e'><lane id='e_0' index='0' shape='1,2,3,4 5,6'/></edge></net>")
    with pytest.raises(MapError, match="broken.net.xml.*'e_0'.*malformed shape"):
        load_map(bad, cache_dir=tmp_path / "cache")


def test_xodr_through_the_loader(tmp_path: Path, straight_xodr: Path) -> None:
    m = load_map(straight_xodr, cache_dir=tmp_path / "cache")
    assert m.source == str(straight_xodr)
    assert m.content_hash == hashlib.sha256(straight_xodr.read_bytes()).hexdigest()
    assert m.num_lanes == 2
    net = sumo_net_path(straight_xodr, tmp_path / "cache")
    assert net.name == "straight.net.xml" and net.parent.parent == tmp_path / "cache"
    assert "<lane " in net.read_text()
    assert sumo_net_path(net) == net
