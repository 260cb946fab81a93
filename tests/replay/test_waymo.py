"""Waymo Open Motion: a TFRecord of Scenario protos written here (no TensorFlow), its tracks and
map features read, checksums verified, and an agent driven on the scenario's own map."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import yaml

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import Role
from smarts.env.assembly import build_simulation
from smarts.replay import read_recording
from smarts.replay.lane_map import compile_lane_map
from smarts.replay.tfrecord import crc32c, masked_crc, read_records
from smarts.replay.waymo_proto import message_classes
from smarts.scenario import load_scenario
from tests.replay.files import WAYMO_ID, waymo_scenario, write_waymo


def test_crc32c_and_its_mask():
    assert crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value
    assert crc32c(b"") == 0
    crc = crc32c(b"abc")
    assert masked_crc(b"abc") == ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + 0xA282EAD8) & 0xFFFFFFFF


def test_field_numbers_match_the_published_wire_format():
    # ObjectState{center_x = 2 (double), length = 5 (float), valid = 11 (bool)} encoded by hand
    raw = bytes([2 << 3 | 1]) + struct.pack("<d", 12.5) + bytes([5 << 3 | 5]) + struct.pack("<f", 4.5)
    raw += bytes([11 << 3 | 0, 1])
    state = message_classes()["ObjectState"].FromString(raw)
    assert state.center_x == 12.5 and state.length == 4.5 and state.valid
    # Scenario{scenario_id = 5 (string), tracks = 2 {id = 1, object_type = 2}}
    track = bytes([1 << 3, 42, 2 << 3, 1])
    raw = bytes([5 << 3 | 2, 3]) + b"abc" + bytes([2 << 3 | 2, len(track)]) + track
    scenario = message_classes()["Scenario"].FromString(raw)
    assert scenario.scenario_id == "abc" and scenario.tracks[0].id == 42 and scenario.tracks[0].object_type == 1


def test_tracks_and_map_are_read(tmp_path):
    rec = read_recording("waymo", write_waymo(tmp_path / "s.tfrecord"))
    assert rec.ids == ["20", "7", "8"]  # the never-valid vehicle is left out; the pedestrian replays
    assert rec.kind_name(0) == "pedestrian" and rec.skipped == {"9": "a passenger never valid"}
    assert rec.first.tolist() == [0, 0, 10] and rec.count.tolist() == [91, 91, 51] and rec.dt == 0.1
    np.testing.assert_allclose(rec.track(2)[:, 0], 20.0 + 0.8 * np.arange(10, 61), atol=1e-9)
    np.testing.assert_allclose(rec.track(2)[:, 3], 8.0, atol=1e-6)
    assert rec.length == pytest.approx([0.6, 4.8, 5.5]) and rec.width == pytest.approx([0.6, 2.0, 2.2])
    dm = rec.road_map
    assert dm.lane_ids == ["1001", "1002", "1003", "1004"] and dm.stop_signs.tolist() == [[195.0, -2.0]]
    m = compile_lane_map(dm)
    assert m.road_ids == ["road_1001", "road_1003"] and m.lane_index.tolist() == [0, 1, 0, 1]
    assert m.lane_left.tolist() == [1, -1, 3, -1]
    assert [m.succ[m.succ_offsets[i] : m.succ_offsets[i + 1]].tolist() for i in range(4)] == [[2], [3], [], []]
    np.testing.assert_allclose(m.lane_speed_limit, 25 * 0.44704)
    # widths from the road edge and line beside each lane (the left lanes: twice the one side known)
    np.testing.assert_allclose(m.lane_width, 3.7)
    # the stop sign, with the lane it controls, is part of the compiled map and survives a save
    assert m.stop_sign_xy.tolist() == [[195.0, -2.0]] and m.stop_sign_lane.tolist() == [m.lane_index_of["1003"]]
    m.save(tmp_path / "map.npz")
    again = type(m).load(tmp_path / "map.npz")
    assert again.stop_sign_xy.tolist() == [[195.0, -2.0]] and again.stop_sign_lane.tolist() == [m.lane_index_of["1003"]]


def test_a_scenario_is_picked_by_id_or_index(tmp_path):
    path = write_waymo(tmp_path / "s.tfrecord", [waymo_scenario("first"), waymo_scenario("second")])
    assert len(list(read_records(path))) == 2
    assert read_recording("waymo", path, scenario="second").source.endswith("(scenario second)")
    assert read_recording("waymo", path, scenario="1").source.endswith("(scenario second)")
    with pytest.raises(ReplayError, match=r"no scenario 'third' \(the file holds 2: first, second\)"):
        read_recording("waymo", path, scenario="third")


def test_truncated_and_corrupted_records_name_file_and_record(tmp_path):
    path = write_waymo(tmp_path / "s.tfrecord", [waymo_scenario("a"), waymo_scenario("b")])
    data = path.read_bytes()
    first_len = struct.unpack("<Q", data[:8])[0]
    second = 12 + first_len + 4
    cut = tmp_path / "cut.tfrecord"
    cut.write_bytes(data[: second + 100])
    with pytest.raises(ReplayError) as err:
        list(read_records(cut))
    assert (
        str(cut) in str(err.value)
        and f"record 1 at byte {second}: truncated (the header claims {first_len} "
        "data bytes and a 4-byte checksum; 88 bytes follow it)"
        in str(err.value)
    )
    bad = bytearray(data)
    bad[40] ^= 0xFF
    (tmp_path / "bad.tfrecord").write_bytes(bytes(bad))
    with pytest.raises(ReplayError, match=r"bad.tfrecord: record 0 at byte 0: the data's checksum does not match"):
        read_recording("waymo", tmp_path / "bad.tfrecord")
    (tmp_path / "text.tfrecord").write_text("this is not a tfrecord file at all")
    with pytest.raises(ReplayError, match=r"text.tfrecord: is a text file \(NGSIM trajectories are read with --format "
                                          r"ngsim\), not a waymo file"):  # fmt: skip
        read_recording("waymo", tmp_path / "text.tfrecord")
    (tmp_path / "binary.tfrecord").write_bytes(bytes(range(200, 256)) * 4)
    with pytest.raises(ReplayError, match=r"binary.tfrecord: record 0 at byte 0: the length's checksum does not match"):
        read_recording("waymo", tmp_path / "binary.tfrecord")
    from smarts.replay.tfrecord import write_records

    write_records(tmp_path / "junk.tfrecord", [b"\xff\xff\xff"])
    with pytest.raises(ReplayError, match=r"junk.tfrecord: record 0: not a Scenario protocol buffer"):
        read_recording("waymo", tmp_path / "junk.tfrecord")


def test_agent_takes_over_a_vehicle_on_the_scenario_map(tmp_path):
    write_waymo(tmp_path / "womd.tfrecord")
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "map": "replay", "episode_steps": 80,
        "replay": {"format": "waymo", "path": "womd.tfrecord", "scenario": WAYMO_ID, "take_over": {"ego": 7}},
        "agents": [{"id": "ego", "action_space": "target_pose"}],
    }))  # fmt: skip
    sim = build_simulation(load_scenario(path))
    sim.reset()
    t = sim.table
    row = int(sim.agent_row[0])
    assert t.ids[row] == "replay-7" and t.role[row] == Role.AGENT
    assert (t.x[row], t.y[row], t.speed[row], t.length[row]) == pytest.approx((5.0, 0.0, 10.0, 4.8))
    assert sim.missions[0].goal_xy == pytest.approx([5.0 + 90.0, 0.0])
    for step in range(1, 41):
        x = 5.0 + 1.0 * step
        sim.step({"ego": np.array([x, 0.0, 0.0])})
        row8 = t.row_of.get("replay-8")
        assert (row8 is not None) == (10 <= step <= 60)
        if row8 is not None:
            assert t.x[row8] == pytest.approx(20.0 + 0.8 * step) and t.role[row8] == Role.REPLAY
    assert t.x[row] == pytest.approx(45.0, abs=0.1) and sim.road_map.lane_ids[t.lane[row]] == "1001"


def test_env_drives_an_agent_among_the_recorded_vehicles(tmp_path):
    from smarts.env import DrivingParallelEnv

    write_waymo(tmp_path / "womd.tfrecord")
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "map": "replay",
        "replay": {"format": "waymo", "path": "womd.tfrecord", "take_over": {"ego": 7}, "reactive": "interaction"},
        "agents": [{"id": "ego"}],
    }))  # fmt: skip
    env = DrivingParallelEnv(str(path))
    try:
        obs, _ = env.reset(seed=0)
        for _ in range(30):
            obs, rewards, terminations, *_ = env.step({"ego": np.array([1.0, 0.0, 0.0], np.float32)})
            assert env.observation_space("ego").contains(obs["ego"]) and not terminations["ego"]
        neighbours = obs["ego"]["neighbours"]
        # vehicle 8 and the pedestrian (flagged as one) beside the road
        assert (np.abs(neighbours).sum(axis=1) > 0).sum() == 2 and (neighbours[:, 8] == 1.0).sum() == 1
        assert rewards["ego"] > 0
    finally:
        env.close()


def test_a_stop_sign_without_a_named_lane_controls_the_nearest_lane(tmp_path):
    import dataclasses

    dm = read_recording("waymo", write_waymo(tmp_path / "s.tfrecord")).road_map
    m = compile_lane_map(dataclasses.replace(dm, stop_signs=np.array([[195.0, -2.0], [195.0, -80.0]]),
                                             stop_sign_lanes=[None, None]))  # fmt: skip
    near = m.stop_sign_lane.tolist()
    assert near[1] == -1  # 80 m from every lane: controls none
    assert near[0] >= 0 and m.lane_road[near[0]] == m.lane_road[m.lane_index_of["1003"]]
