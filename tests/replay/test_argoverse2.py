"""Argoverse 2: a scenario folder (parquet track table + map JSON) written here, read with pyarrow,
its lane graph compiled into a RoadMap and an agent driven among its recorded vehicles."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import Role, VehicleType
from smarts.env.assembly import build_simulation
from smarts.maps import project
from smarts.replay import read_recording
from smarts.replay.lane_map import compile_lane_map
from smarts.scenario import load_scenario
from tests.replay.files import AV2_ID, av2_map, av2_tracks, write_av2


def test_tracks_are_read_as_recorded(tmp_path):
    rec = read_recording("argoverse2", write_av2(tmp_path / "scn"))
    assert rec.ids == ["11", "12", "AV", "ped_1"]  # the pedestrian replays as a pedestrian
    assert rec.first.tolist() == [20, 0, 0, 0] and rec.count.tolist() == [60, 50, 110, 110]
    assert rec.vtype.tolist() == [VehicleType.PASSENGER, VehicleType.BUS, VehicleType.PASSENGER, VehicleType.PEDESTRIAN]
    assert rec.kind_name(3) == "pedestrian" and (rec.length[3], rec.width[3]) == (0.5, 0.5)
    track = rec.track(0)
    np.testing.assert_allclose(track[:, 0], 30.0 + 1.2 * np.arange(60), atol=1e-9)
    np.testing.assert_allclose(track[:, 1], 5.25)
    np.testing.assert_allclose(track[:, 3], 12.0)
    assert rec.duration == pytest.approx(10.9)
    # the parquet file itself names the scenario as well as its folder
    assert read_recording("argoverse2", tmp_path / "scn" / f"scenario_{AV2_ID}.parquet").ids == rec.ids


def test_lane_graph_compiles_into_roads_with_neighbours_and_successors(tmp_path):
    rec = read_recording("argoverse2", write_av2(tmp_path / "scn"))
    m = compile_lane_map(rec.road_map)
    assert m.lane_ids == ["101", "102", "201", "202"] and m.road_ids == ["road_101", "road_201"]
    assert m.lane_index.tolist() == [0, 1, 0, 1]
    assert m.lane_left.tolist() == [1, -1, 3, -1] and m.lane_right.tolist() == [-1, 0, -1, 2]
    assert [m.succ[m.succ_offsets[i] : m.succ_offsets[i + 1]].tolist() for i in range(4)] == [[2], [3], [], []]
    np.testing.assert_allclose(m.lane_width, 3.5)
    np.testing.assert_allclose(m.lane_length, 100.0)
    proj = project(m, np.array([[150.0, 5.0]]))
    assert m.lane_ids[proj.lane[0]] == "202" and proj.s[0] == pytest.approx(50.0)


def test_agent_takes_over_the_ego_vehicle_on_the_dataset_map(tmp_path):
    write_av2(tmp_path / "scn")
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "map": "replay", "episode_steps": 100,
        "replay": {"format": "argoverse2", "path": "scn", "take_over": {"ego": "AV"}},
        "agents": [{"id": "ego", "action_space": "relative_target_pose"}],
    }))  # fmt: skip
    sim = build_simulation(load_scenario(path))
    sim.reset()
    t = sim.table
    row = int(sim.agent_row[0])
    assert t.ids[row] == "replay-AV" and t.role[row] == Role.AGENT
    assert (t.x[row], t.y[row], t.speed[row]) == pytest.approx((5.0, 1.75, 10.0))
    assert sim.missions[0].goal_xy == pytest.approx([5.0 + 10.9 * 10.0, 1.75])
    assert sim.road_map.lane_ids[t.lane[row]] == "101"
    bus = t.row_of["replay-12"]
    for step in range(1, 31):
        sim.step({"ego": np.array([1.0, 0.0, 0.0])})  # 10 m/s, as recorded
        if step == 20:
            assert "replay-11" in t.row_of  # vehicle 11 enters at timestep 20
    assert t.x[bus] == pytest.approx(60.0 + 5.0 * 3.0) and t.y[bus] == pytest.approx(1.75)
    other = t.row_of["replay-11"]
    assert t.x[other] == pytest.approx(30.0 + 1.2 * 10) and sim.road_map.lane_ids[t.lane[other]] == "102"
    assert t.x[row] == pytest.approx(35.0, abs=0.5) and not sim.agent_done[0]


def test_malformed_scenarios_name_file_and_field(tmp_path):
    rows = [{k: v for k, v in r.items() if k != "heading"} for r in av2_tracks()]
    folder = write_av2(tmp_path / "a", tracks=rows)
    with pytest.raises(ReplayError) as err:
        read_recording("argoverse2", folder)
    assert f"scenario_{AV2_ID}.parquet" in str(err.value) and "missing column(s) heading" in str(err.value)
    broken = av2_map()
    broken["lane_segments"]["102"]["left_lane_boundary"] = [{"x": 1.0}]
    folder = write_av2(tmp_path / "b", map_data=broken)
    with pytest.raises(ReplayError, match=r"log_map_archive_.*\.json: lane_segments.102.left_lane_boundary"):
        read_recording("argoverse2", folder)
    folder = write_av2(tmp_path / "c")
    (folder / f"log_map_archive_{AV2_ID}.json").write_text("{not json")
    with pytest.raises(ReplayError, match="not a readable map JSON"):
        read_recording("argoverse2", folder)
    (tmp_path / "d").mkdir()
    with pytest.raises(ReplayError, match=r"expected one scenario_<id>.parquet in the folder, found 0"):
        read_recording("argoverse2", tmp_path / "d")
    folder = write_av2(tmp_path / "e")
    (folder / f"scenario_{AV2_ID}.parquet").write_bytes(b"PAR1 truncated")
    with pytest.raises(ReplayError, match=r"scenario_.*\.parquet: not a readable parquet file"):
        read_recording("argoverse2", folder)
    json.loads((tmp_path / "b" / f"log_map_archive_{AV2_ID}.json").read_text())  # the broken map is JSON


def test_env_drives_an_agent_among_the_recorded_vehicles(tmp_path):
    from smarts.env import DrivingParallelEnv

    write_av2(tmp_path / "scn")
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "map": "replay",
        "replay": {"format": "argoverse2", "path": "scn", "take_over": {"ego": "AV"}},
        "agents": [{"id": "ego"}],
    }))  # fmt: skip
    env = DrivingParallelEnv(str(path))
    try:
        obs, _ = env.reset(seed=0)
        seen, pedestrians = 0, 0
        for _ in range(40):
            obs, rewards, terminations, truncations, _ = env.step({"ego": np.array([1.0, 0.0, 0.0], np.float32)})
            assert env.observation_space("ego").contains(obs["ego"]) and not terminations["ego"]
            neighbours = obs["ego"]["neighbours"]
            seen = max(seen, int((np.abs(neighbours).sum(axis=1) > 0).sum()))
            pedestrians = max(pedestrians, int((neighbours[:, 8] == 1.0).sum()))
        # the bus, vehicle 11 and the pedestrian (flagged as one) around it; progress on its route
        assert seen == 3 and pedestrians == 1 and rewards["ego"] > 0
    finally:
        env.close()
