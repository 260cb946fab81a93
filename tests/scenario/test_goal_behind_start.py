"""A goal the route cannot reach, the goal behind the start included: ``smarts scenario validate``
and env construction refuse it naming the agent, and the goal test never fires on a lane position
behind the start. (The road goal test counts a vehicle on the goal road at or past the goal's
offset as arrived, so a goal behind the start on its road would be "reached" at the first step.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from smarts.__main__ import main
from smarts.core.errors import MapError
from smarts.scenario.validate import validate_scenario
from tests.maps.conftest import build_net

BEHIND = "is not ahead of the start (offset 50 on the same road), so the route cannot reach it"


@pytest.fixture(autouse=True)
def _private_cache(monkeypatch, map_cache_dir):
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(map_cache_dir))


def scenario(folder: Path, *missions: dict, map_: str = "builtin:straight_2lane", name: str = "s.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump({"name": "goal_check", "map": map_, "agents": [{"mission": m} for m in missions]}))
    return path


AHEAD = {"start": {"road": "main", "offset": 3}, "goal": {"road": "main", "offset": 50}}

REFUSED = [
    ("same lane", {"start": {"road": "main", "offset": 50}, "goal": {"road": "main", "offset": 10}},
     f"agents[1].mission.goal: offset 10 on road 'main' {BEHIND}"),
    ("any lane of the road", {"start": {"road": "main", "lane": 1, "offset": 50}, "goal": {"road": "main", "offset": 10}},
     f"agents[1].mission.goal: offset 10 on road 'main' {BEHIND}"),
    ("the other lane", {"start": {"road": "main", "lane": 1, "offset": 50}, "goal": {"road": "main", "lane": 0, "offset": 10}},
     f"agents[1].mission.goal: offset 10 on road 'main' {BEHIND}"),
    ("at the start", {"start": {"road": "main", "offset": 50}, "goal": {"road": "main", "offset": 50}},
     f"agents[1].mission.goal: offset 50 on road 'main' {BEHIND}"),
    ("a position behind on a dead end", {"start": {"road": "main", "offset": 50}, "goal": {"position": [10.0, -4.8], "radius": 2}},
     "agents[1].mission.goal.position: lies behind the start on road 'main', and no route leaves that road and comes back"),
    ("a position behind on the other lane", {"start": {"road": "main", "offset": 50}, "goal": {"position": [10.0, -1.6], "radius": 2}},
     "agents[1].mission.goal.position: lies behind the start on road 'main'"),
]  # fmt: skip


@pytest.mark.parametrize("name, mission, problem", REFUSED, ids=[c[0] for c in REFUSED])
def test_validate_and_the_env_refuse_a_goal_behind_the_start_naming_the_agent(tmp_path, capsys, name, mission, problem):
    from smarts.env import DrivingParallelEnv

    file = scenario(tmp_path, AHEAD, mission)  # agent 0 is fine: the problem names agent 1
    assert main(["scenario", "validate", str(file)]) == 2
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{file}: {problem}"), lines
    with pytest.raises(MapError) as raised:
        DrivingParallelEnv(str(file))
    assert str(raised.value).startswith(f"{file}: {problem}")


def test_a_goal_ahead_on_the_same_road_is_reached_by_driving_not_at_once(tmp_path):
    from smarts.env import DrivingParallelEnv

    file = scenario(
        tmp_path, {"start": {"road": "main", "offset": 50, "speed": 10}, "goal": {"road": "main", "offset": 60}}
    )
    assert validate_scenario(file).valid
    env = DrivingParallelEnv(str(file))
    env.reset(seed=0)
    agent = env.agents[0]
    reached_at = None
    for step in range(1, 40):
        _, _, terminated, _, _ = env.step({agent: np.array([1.0, 0.0, 0.0])})  # 1 m a step
        if terminated[agent]:
            reached_at = step
            break
    env.close()
    assert reached_at is not None and reached_at > 5  # 10 m at about 10 m/s: about ten steps, not one


RING_NODES = """<nodes>
  <node id="A" x="0" y="0"/> <node id="B" x="120" y="0"/> <node id="C" x="120" y="120"/> <node id="D" x="0" y="120"/>
</nodes>"""
RING_EDGES = """<edges>
  <edge id="AB" from="A" to="B" numLanes="1" speed="13.89"/> <edge id="BC" from="B" to="C" numLanes="1" speed="13.89"/>
  <edge id="CD" from="C" to="D" numLanes="1" speed="13.89"/> <edge id="DA" from="D" to="A" numLanes="1" speed="13.89"/>
</edges>"""
"""A one-way ring: a route can leave road AB and come back to it."""


@pytest.fixture(scope="module")
def ring(tmp_path_factory) -> Path:
    return build_net(tmp_path_factory.mktemp("ring"), "ring", RING_NODES, RING_EDGES)


def test_on_a_ring_a_position_behind_the_start_is_reached_round_the_ring_and_not_at_once(tmp_path, ring):
    """The route leaves the start road and comes back; the vehicle is not at its goal on the way out."""
    from smarts.core.missions import lane_pose_at, resolve_mission
    from smarts.env import DrivingParallelEnv
    from smarts.maps import load_map

    road_map = load_map(ring)
    lane = int(road_map.road_lanes(road_map.road("AB"))[0])
    goal_xy, _ = lane_pose_at(road_map, lane, 20.0)
    behind = {"start": {"road": "AB", "offset": 60, "speed": 5},
              "goal": {"position": [float(goal_xy[0]), float(goal_xy[1])], "radius": 3}}  # fmt: skip
    file = scenario(tmp_path, behind, map_=str(ring))
    result = validate_scenario(file)
    assert result.valid, result.problems
    resolved = resolve_mission(road_map, "agent_0", result.spec.agents[0].mission, "agents[0].mission")
    roads = [road_map.road_ids[int(road_map.lane_road[ln])] for ln in resolved.route]
    assert [r for r in roads if not r.startswith(":")] == ["AB", "BC", "CD", "DA", "AB"]
    assert np.hypot(*(resolved.path_xy[-1] - goal_xy)) < 3.0  # the path ends at the goal, round the ring
    env = DrivingParallelEnv(str(file))
    env.reset(seed=0)
    agent = env.agents[0]
    for _ in range(20):  # 2 s at 5 m/s: still on AB, moving away from the goal behind it
        _, _, terminated, _, infos = env.step({agent: np.array([0.5, 0.0, 0.0])})
        assert not terminated[agent], infos[agent]
    env.close()


def test_on_a_ring_a_road_goal_behind_the_start_is_still_refused(tmp_path, ring):
    """Even where a route could come back, the goal test would count the vehicle as arrived at once."""
    file = scenario(
        tmp_path, {"start": {"road": "AB", "offset": 50}, "goal": {"road": "AB", "offset": 10}}, map_=str(ring)
    )
    result = validate_scenario(file)
    assert len(result.problems) == 1
    assert result.problems[0].startswith(f"{file}: agents[0].mission.goal: offset 10 on road 'AB' {BEHIND}")
