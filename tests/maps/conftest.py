"""Small road networks built with the real netconvert, shared by the map tests."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from smarts.maps.opendrive import netconvert_binary
from smarts.maps.road_map import RoadMap
from smarts.maps.sumo_net import compile_sumo_net

STRAIGHT_NODES = """<nodes>
  <node id="A" x="0" y="0"/>
  <node id="B" x="200" y="0"/>
</nodes>"""
# Two 3.5 m car lanes plus a 2 m sidewalk (SUMO lane 0), centred on y = -1 by netconvert, so car
# lane centres lie at y = -1.75 (AB_1) and y = +1.75 (AB_2).
STRAIGHT_EDGES = """<edges>
  <edge id="AB" from="A" to="B" numLanes="2" speed="20" width="3.5" sidewalkWidth="2.0"
        spreadType="center"/>
</edges>"""

CROSS_NODES = """<nodes>
  <node id="C" x="0" y="0" type="priority"/>
  <node id="N" x="0" y="100"/>
  <node id="S" x="0" y="-100"/>
  <node id="E" x="100" y="0"/>
  <node id="W" x="-100" y="0"/>
</nodes>"""
CROSS_EDGES = (
    """<edges>
"""
    + "\n".join(
        f'  <edge id="{a}{b}" from="{a}" to="{b}" numLanes="1" speed="13.89"/>'
        for a, b in [("W", "C"), ("C", "W"), ("E", "C"), ("C", "E"), ("N", "C"), ("C", "N"), ("S", "C"), ("C", "S")]
    )
    + """
</edges>"""
)

# One 100 m road heading east from (10, 20) with two right-hand driving lanes: -1 (3.5 m wide,
# next to the reference line) and -2 (3.0 m, outermost, so it becomes the rightmost lane).
STRAIGHT_XODR = """<?xml version="1.0" standalone="yes"?>
<OpenDRIVE>
  <header revMajor="1" revMinor="4" name="straight" version="1.00"/>
  <road name="R" length="100.0" id="7" junction="-1">
    <link/>
    <planView>
      <geometry s="0.0" x="10.0" y="20.0" hdg="0.0" length="100.0"><line/></geometry>
    </planView>
    <lanes>
      <laneSection s="0.0">
        <center><lane id="0" type="none" level="false"><link/></lane></center>
        <right>
          <lane id="-1" type="driving" level="false"><link/>
            <width sOffset="0.0" a="3.5" b="0.0" c="0.0" d="0.0"/></lane>
          <lane id="-2" type="driving" level="false"><link/>
            <width sOffset="0.0" a="3.0" b="0.0" c="0.0" d="0.0"/></lane>
        </right>
      </laneSection>
    </lanes>
  </road>
</OpenDRIVE>
"""


def build_net(out_dir: Path, name: str, nodes: str, edges: str) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    nod = out_dir / f"{name}.nod.xml"
    edg = out_dir / f"{name}.edg.xml"
    net = out_dir / f"{name}.net.xml"
    nod.write_text(nodes)
    edg.write_text(edges)
    subprocess.run(
        [
            netconvert_binary(),
            "--node-files",
            str(nod),
            "--edge-files",
            str(edg),
            "--output-file",
            str(net),
            "--no-turnarounds",
            "--offset.disable-normalization",
        ],
        check=True,
        capture_output=True,
    )
    assert "<lane " in net.read_text()
    return net


@pytest.fixture(scope="session")
def straight_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out_dir = tmp_path_factory.mktemp("straight")
    return build_net(out_dir, "straight", STRAIGHT_NODES, STRAIGHT_EDGES)


@pytest.fixture(scope="session")
def cross_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_net(tmp_path_factory.mktemp("cross"), "cross", CROSS_NODES, CROSS_EDGES)


@pytest.fixture(scope="session")
def straight_xodr(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("xodr") / "straight.xodr"
    path.write_text(STRAIGHT_XODR)
    return path


@pytest.fixture(scope="session")
def straight_map(straight_net: Path) -> RoadMap:
    return compile_sumo_net(straight_net)


@pytest.fixture(scope="session")
def cross_map(cross_net: Path) -> RoadMap:
    return compile_sumo_net(cross_net)
