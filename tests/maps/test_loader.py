"""Loading maps by file type, with the on-disk and in-process caches."""

from __future__ import annotations

import hashlib
import shutil
import signal
import subprocess
import sys
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from smarts import cache
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


# ---------------------------------------------------------------- damaged and unwritable caches
def cached_npz(cache_dir: Path, source: Path) -> Path:
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    return cache_dir / f"{digest}-v{FORMAT_VERSION}.npz"


def test_truncated_compiled_map_is_rebuilt(tmp_path: Path, straight_net: Path) -> None:
    cache_dir = tmp_path / "cache"
    clear_memory_cache()
    first = load_map(straight_net, cache_dir=cache_dir)
    entry = cached_npz(cache_dir, straight_net)
    whole = entry.read_bytes()
    for cut in (len(whole) // 2, len(whole) - 30):  # a cut inside the arrays and one in the index
        entry.write_bytes(whole[:cut])
        clear_memory_cache()
        again = load_map(straight_net, cache_dir=cache_dir)
        assert_same_map(first, again)
        assert_same_map(first, RoadMap.load(entry))  # the entry itself was replaced
    assert sorted(p.name for p in cache_dir.iterdir()) == [entry.name]


def test_compiled_map_with_a_changed_array_is_rebuilt(tmp_path: Path, straight_net: Path) -> None:
    cache_dir = tmp_path / "cache"
    clear_memory_cache()
    first = load_map(straight_net, cache_dir=cache_dir)
    entry = cached_npz(cache_dir, straight_net)
    with np.load(entry) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["lane_speed_limit"] = arrays["lane_speed_limit"] * 2  # a well-formed file, wrong content
    np.savez(entry, **arrays)
    with pytest.raises(MapError, match="does not match its recorded SHA-256"):
        RoadMap.load(entry)
    clear_memory_cache()
    assert_same_map(first, load_map(straight_net, cache_dir=cache_dir))
    assert_same_map(first, RoadMap.load(entry))


def test_writer_killed_before_the_rename_leaves_no_entry(tmp_path: Path, straight_net: Path) -> None:
    cache_dir = tmp_path / "cache"
    code = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from smarts.maps import load_map\n"
        "real = os.replace\n"
        "def dying(src, dst):\n"
        "    if str(dst).endswith('.npz'):\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return real(src, dst)\n"
        "os.replace = dying\n"
        "load_map(Path(sys.argv[1]), cache_dir=Path(sys.argv[2]))\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(straight_net), str(cache_dir)])
    assert done.returncode == -signal.SIGKILL
    entry = cached_npz(cache_dir, straight_net)
    assert not entry.exists()
    assert [p.name.startswith(".tmp-") for p in cache_dir.iterdir()] == [True]  # written, unused
    clear_memory_cache()
    m = load_map(straight_net, cache_dir=cache_dir)
    assert m.lane_ids == ["AB_1", "AB_2"] and RoadMap.load(entry).lane_ids == m.lane_ids


def test_damaged_converted_network_of_an_xodr_is_rebuilt(tmp_path: Path, straight_xodr: Path) -> None:
    cache_dir = tmp_path / "cache"
    net = sumo_net_path(straight_xodr, cache_dir)
    whole = net.read_bytes()
    assert (net.parent / "SHA256SUMS").is_file()
    net.write_bytes(whole[: len(whole) // 2])
    assert sumo_net_path(straight_xodr, cache_dir) == net
    rebuilt = net.read_bytes()  # the same network (only the header's build time may differ)
    assert len(rebuilt) == len(whole) and rebuilt.rstrip().endswith(b"</net>")
    clear_memory_cache()
    assert load_map(straight_xodr, cache_dir=cache_dir).num_lanes == 2


def test_corrupt_user_map_is_an_error_naming_the_file(tmp_path: Path, straight_net: Path, straight_xodr: Path) -> None:
    cache_dir = tmp_path / "cache"
    net = tmp_path / "half.net.xml"
    whole = straight_net.read_bytes()
    net.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(MapError, match=r"half\.net\.xml: not a valid XML file"):
        load_map(net, cache_dir=cache_dir)
    xodr = tmp_path / "half.xodr"
    text = straight_xodr.read_bytes()
    xodr.write_bytes(text[: len(text) // 2])
    with pytest.raises(MapError, match=r"half\.xodr: netconvert could not convert"):
        load_map(xodr, cache_dir=cache_dir)
    with pytest.raises(MapError, match=r"half\.xodr"):
        sumo_net_path(xodr, cache_dir)
    # Nothing was cached for either file but the record of the failed conversion (so the next
    # load fails at once); no temporary left behind.
    digest = hashlib.sha256(xodr.read_bytes()).hexdigest()
    assert [p.name for p in cache_dir.iterdir()] == [f"{digest}-net.failed"]


def test_unwritable_cache_falls_back_to_a_temporary_one_with_one_warning(
    tmp_path: Path, straight_net: Path, straight_xodr: Path, fresh_fallback: None
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    cache_dir = blocker / "maps"
    clear_memory_cache()
    with pytest.warns(cache.UnwritableCacheWarning) as record:
        m = load_map(straight_net, cache_dir=cache_dir)
        assert load_map(straight_xodr, cache_dir=cache_dir).num_lanes == 2
    assert len(record) == 1
    assert str(cache_dir) in str(record[0].message)
    assert "SMARTS_CACHE_DIR" in str(record[0].message)
    fallback = cache.fallback_home(create=False)
    assert fallback is not None and fallback.name.startswith("smarts-cache-")
    assert cached_npz(fallback / "maps", straight_net).is_file()

    clear_memory_cache()  # the next load in this process reads the temporary cache
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_same_map(m, load_map(straight_net, cache_dir=cache_dir))
        assert sumo_net_path(straight_xodr, cache_dir).is_relative_to(fallback)


def test_unwritable_cache_from_the_environment(
    tmp_path: Path, straight_net: Path, monkeypatch: pytest.MonkeyPatch, fresh_fallback: None
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(blocker / "cache"))
    clear_memory_cache()
    with pytest.warns(cache.UnwritableCacheWarning, match="SMARTS_CACHE_DIR"):
        assert load_map(straight_net).lane_ids == ["AB_1", "AB_2"]


def test_a_copy_of_the_same_map_keeps_its_own_source(tmp_path: Path, straight_net: Path) -> None:
    """The caches are keyed by content, but SUMO later reads ``source``: it must be this file."""
    cache_dir = tmp_path / "cache"
    first, second = tmp_path / "a" / "road.net.xml", tmp_path / "b" / "road.net.xml"
    for copy in (first, second):
        copy.parent.mkdir()
        shutil.copy(straight_net, copy)
    clear_memory_cache()
    a = load_map(first, cache_dir=cache_dir)
    b = load_map(second, cache_dir=cache_dir)  # same content: from the disk cache
    assert (a.source, b.source) == (str(first), str(second))
    shutil.rmtree(first.parent)
    assert sumo_net_path(load_map(second, cache_dir=cache_dir).source) == second
    clear_memory_cache()
    assert load_map(second, cache_dir=cache_dir).source == str(second)


# ---------------------------------------------------------------- OpenDRIVE netconvert rejects
@pytest.fixture
def netconvert_runs(monkeypatch: pytest.MonkeyPatch) -> list:
    """Counts netconvert runs (each still runs the real netconvert)."""
    from smarts.maps import opendrive

    runs: list = []
    real_run = opendrive.subprocess.run

    def counting_run(command, *args, **kwargs):
        runs.append(command)
        return real_run(command, *args, **kwargs)

    monkeypatch.setattr(opendrive.subprocess, "run", counting_run)
    return runs


def test_a_failed_conversion_is_cached_and_fails_fast_with_the_same_message(
    tmp_path: Path, netconvert_runs: list
) -> None:
    bad = tmp_path / "broken.xodr"
    bad.write_text("<OpenDRIVE><road id='1' length='x'>")
    with pytest.raises(MapError, match="broken.xodr: netconvert could not convert") as first:
        load_map(bad, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 2  # strict, then --ignore-errors
    assert "Invalid Number Format" in str(first.value)  # netconvert's own words
    for _ in range(2):
        with pytest.raises(MapError) as again:
            load_map(bad, cache_dir=tmp_path / "cache")
        assert str(again.value) == str(first.value)
        with pytest.raises(MapError) as via_sumo:
            sumo_net_path(bad, tmp_path / "cache")
        assert str(via_sumo.value) == str(first.value)
    assert len(netconvert_runs) == 2  # not converted again
    # the same content under another name fails fast too, naming that file
    copy = tmp_path / "copy.xodr"
    copy.write_bytes(bad.read_bytes())
    with pytest.raises(MapError, match="copy.xodr: netconvert could not convert"):
        load_map(copy, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 2
    # an edited file is converted again
    bad.write_text("<OpenDRIVE><road id='2' length='y'>")
    with pytest.raises(MapError, match="broken.xodr"):
        load_map(bad, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 4


def test_a_failure_recorded_by_another_netconvert_is_retried(tmp_path: Path, netconvert_runs: list) -> None:
    import json

    bad = tmp_path / "broken.xodr"
    bad.write_text("<OpenDRIVE><road id='1' length='x'>")
    with pytest.raises(MapError):
        load_map(bad, cache_dir=tmp_path / "cache")
    (record,) = (tmp_path / "cache").glob("*-net.failed")
    data = json.loads(record.read_text())
    record.write_text(json.dumps({**data, "netconvert": "an older netconvert"}))
    with pytest.raises(MapError):
        load_map(bad, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 4
    record.write_text("{partial")  # a damaged record: converted (and recorded) again
    with pytest.raises(MapError):
        load_map(bad, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 6
    assert json.loads(record.read_text())["netconvert"] == data["netconvert"]


def test_a_network_built_ignoring_errors_warns_on_every_load(
    tmp_path: Path, netconvert_runs: list, monkeypatch: pytest.MonkeyPatch
) -> None:
    from smarts.maps import loader
    from smarts.maps.opendrive import MapWarning
    from tests.maps.conftest import STRAIGHT_XODR
    from tests.maps.test_opendrive import UNKNOWN_ROAD_LINK

    path = tmp_path / "lenient.xodr"
    path.write_text(STRAIGHT_XODR.replace("</OpenDRIVE>", UNKNOWN_ROAD_LINK))
    monkeypatch.setattr(loader, "_warned_lenient", set())
    with pytest.warns(MapWarning, match="road '55' is not known") as record:
        m = load_map(path, cache_dir=tmp_path / "cache")
        sumo_net_path(path, tmp_path / "cache")
    assert len(record) == 1 and m.num_lanes == 2
    # a later process (memory caches empty) loads from the disk cache and is told again
    clear_memory_cache()
    monkeypatch.setattr(loader, "_warned_lenient", set())
    with pytest.warns(MapWarning, match="road '55' is not known"):
        load_map(path, cache_dir=tmp_path / "cache")
    assert len(netconvert_runs) == 2  # converted once
