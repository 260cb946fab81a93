"""OpenDRIVE conversion with the real netconvert."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smarts.maps import MapError, on_road, project
from smarts.maps.opendrive import convert_opendrive
from smarts.maps.sumo_net import compile_sumo_net


def test_straight_two_lane_road(tmp_path: Path, straight_xodr: Path) -> None:
    net = convert_opendrive(straight_xodr, tmp_path / "out")
    assert net == tmp_path / "out" / "straight.net.xml"
    m = compile_sumo_net(net)
    assert m.num_lanes == 2 and len(m.road_ids) == 1
    assert not m.lane_internal.any()
    # Rightmost lane first: OpenDRIVE lane -2 (3.0 m) then -1 (3.5 m); coordinates kept as in the
    # file (reference line y = 20 from x = 10 to 110).
    np.testing.assert_allclose(m.lane_width, [3.0, 3.5])
    np.testing.assert_allclose(m.lane_length, [100.0, 100.0], atol=1e-6)
    np.testing.assert_allclose(m.lane_polyline(0), [[10.0, 15.0], [110.0, 15.0]], atol=1e-6)
    np.testing.assert_allclose(m.lane_polyline(1), [[10.0, 18.25], [110.0, 18.25]], atol=1e-6)
    assert m.lane_left[0] == 1 and m.lane_right[1] == 0
    p = project(m, np.array([[60.0, 18.0]]), np.zeros(1))
    assert p.lane[0] == 1 and p.s[0] == pytest.approx(50.0) and p.t[0] == pytest.approx(-0.25)
    assert on_road(m, np.array([[60.0, 14.0], [60.0, 21.0]])).tolist() == [True, False]


def test_invalid_xodr_reports_netconvert_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.xodr"
    bad.write_text("<OpenDRIVE><road id='1' length='x'>")
    with pytest.raises(MapError, match="bad.xodr.*netconvert") as info:
        convert_opendrive(bad, tmp_path / "out")
    assert "rror" in str(info.value)  # netconvert's own error text is included
    assert not list((tmp_path / "out").glob("*.net.xml"))


def test_missing_xodr(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="gone.xodr.*not found"):
        convert_opendrive(tmp_path / "gone.xodr", tmp_path)
