"""OpenDRIVE conversion with the real netconvert."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smarts.maps import MapError, on_road, project
from smarts.maps.opendrive import IGNORED_ERRORS_NAME, MapWarning, convert_opendrive
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


# A junction whose lane link names a road the file does not have: netconvert's strict mode
# rejects the whole file ("incoming road '55' is not known"); with --ignore-errors the rest of the
# network converts.
UNKNOWN_ROAD_LINK = """
  <junction id="1" name="j">
    <connection id="0" incomingRoad="55" connectingRoad="7" contactPoint="start">
      <laneLink from="-1" to="-1"/>
    </connection>
  </junction>
</OpenDRIVE>"""


def test_file_netconvert_rejects_in_strict_mode_converts_ignoring_errors_with_a_warning(
    tmp_path: Path,
) -> None:
    from tests.maps.conftest import STRAIGHT_XODR

    path = tmp_path / "lenient.xodr"
    path.write_text(STRAIGHT_XODR.replace("</OpenDRIVE>", UNKNOWN_ROAD_LINK))
    with pytest.warns(MapWarning, match=r"lenient.xodr.*--ignore-errors(.|\n)*road '55' is not known"):
        net = convert_opendrive(path, tmp_path / "out")
    m = compile_sumo_net(net)
    assert m.num_lanes == 2  # the road itself is there
    assert "road '55'" in (tmp_path / "out" / IGNORED_ERRORS_NAME).read_text()
