"""Recordings as the datasets publish them (files written here in the published layouts): the NGSIM
portal's CSV and the original header-less .txt, Waymo scenarios with jittery timestamps, partial lane
neighbours, signal states, pedestrians, cyclists, crosswalks and bike lanes, Argoverse 2 maps with
crossings, and what goes wrong with them (non-finite values, the wrong file, a take-over that cannot
be driven), each through the reader, the simulation or the env."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from smarts.core.errors import MapError, ReplayError, ScenarioError
from smarts.core.events import Event
from smarts.core.vehicle_table import Role, VehicleType
from smarts.env.assembly import build_simulation
from smarts.maps.road_map import MARK_BIKE_LANE, MARK_CROSSWALK, MARK_SPEED_BUMP, RoadMap
from smarts.maps.routing import shortest_route
from smarts.replay import read_recording
from smarts.replay.lane_map import compile_lane_map
from smarts.replay.recording import DatasetMap
from smarts.scenario import load_scenario
from smarts.traffic.signals import GREEN, RED
from tests.replay.files import (
    AV2_ID,
    JUNCTION_ID,
    LANE0_Y,
    NGSIM_HEADER,
    av2_map_with_crossings,
    av2_tracks,
    slow_car,
    three_vehicles,
    waymo_junction,
    write_av2,
    write_ngsim,
    write_ngsim_portal,
    write_ngsim_txt,
    write_waymo,
)

ALIGN = {"swap_xy": True, "flip_y": True}


def _scenario(tmp_path: Path, body: dict) -> Path:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(body))
    return path


def _replayed(sim) -> set[str]:
    t = sim.table
    return {t.ids[r] for r in t.alive_rows if t.ids[r].startswith("replay-")}


# ---------------------------------------------------------------------------- NGSIM as published
def test_the_portal_csv_is_read_one_site_at_a_time(tmp_path):
    # the portal spells v_length, adds Location and serves every site in one file
    path = write_ngsim_portal(tmp_path / "portal.csv", {"i-80": three_vehicles(), "us-101": three_vehicles()})
    rec = read_recording("ngsim", path, scenario="i-80", **ALIGN)
    reference = read_recording("ngsim", write_ngsim(tmp_path / "one.csv", three_vehicles()), **ALIGN)
    assert rec.ids == reference.ids and rec.count.tolist() == reference.count.tolist()
    np.testing.assert_array_equal(rec.x, reference.x)
    np.testing.assert_array_equal(rec.length, reference.length)
    # the API's all-lower-case names are the same columns
    lower = write_ngsim_portal(tmp_path / "lower.csv", {"i-80": three_vehicles()}, lower=True)
    np.testing.assert_array_equal(read_recording("ngsim", lower, **ALIGN).y, reference.y)
    # in a scenario file, replay.scenario names the site
    body = {"map": "builtin:straight_2lane", "replay": {"format": "ngsim", "path": "portal.csv", "scenario": "us-101",
            **ALIGN, "take_over": {"ego": 2}}, "agents": [{"id": "ego"}]}  # fmt: skip
    sim = build_simulation(load_scenario(_scenario(tmp_path, body)))
    sim.reset()
    assert sim.table.ids[int(sim.agent_row[0])] == "replay-2"


def test_the_original_txt_without_a_header_is_read(tmp_path):
    path = write_ngsim_txt(tmp_path / "trajectories-0400-0415.txt", three_vehicles())
    assert path.read_text().splitlines()[0].split()[:2] == ["1", "100"]  # numbers from the first line on
    rec = read_recording("ngsim", path, **ALIGN)
    reference = read_recording("ngsim", write_ngsim(tmp_path / "one.csv", three_vehicles()), **ALIGN)
    assert rec.ids == reference.ids and rec.first.tolist() == reference.first.tolist()
    np.testing.assert_allclose(rec.x, reference.x, atol=1e-9)
    assert rec.vtype.tolist() == [VehicleType.PASSENGER, VehicleType.TRUCK, VehicleType.PASSENGER]
    lines = path.read_text().splitlines()
    lines[4] = lines[4].replace(lines[4].split()[4], "x1.5", 1)
    (tmp_path / "bad.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(ReplayError, match=r"bad.txt: column 5 \(Local_X\): expected a number, got 'x1.5' in line 5"):
        read_recording("ngsim", tmp_path / "bad.txt")
    (tmp_path / "short.txt").write_text("1 2 3 4\n")
    with pytest.raises(ReplayError, match=r"short.txt: line 1 has 4 column\(s\); the NGSIM trajectory layout"):
        read_recording("ngsim", tmp_path / "short.txt")


def test_a_slow_car_keeps_pointing_along_its_motion(tmp_path):
    # stop-and-go between standing and 2 m/s with NGSIM-like jitter of 0.15 m: headings come from
    # chords longer than the jitter (the old per-frame estimate was off by up to 180 degrees here)
    for seed in range(3):
        v, _ = slow_car(seed=seed, jitter=0.15)
        rec = read_recording("ngsim", write_ngsim(tmp_path / f"slow{seed}.csv", {"9": v}), **ALIGN)
        error = np.degrees(np.abs(rec.track(0)[:, 2]))
        assert error.max() < 10.0 and np.percentile(error, 95) < 5.0, (seed, error.max())
        # so the box centre stays in its lane: half a length behind the front, along the lane
        assert np.abs(rec.track(0)[:, 1] - LANE0_Y).max() < 0.8


def test_the_heading_baseline_follows_the_files_jitter():
    from smarts.replay.recording import MAX_BASELINE, MIN_BASELINE, heading_baseline

    x = np.arange(500) * 1.0
    flat = heading_baseline(x, np.zeros(500), np.array([500]), 5)
    jitter = np.random.default_rng(0).normal(0, 0.1, (2, 500))
    noisy = heading_baseline(x + jitter[0], jitter[1], np.array([500]), 5)
    assert flat == MIN_BASELINE and MIN_BASELINE < noisy < MAX_BASELINE
    # 0.1 m of jitter, smoothed over 5 frames, within 2 degrees: sqrt(2) * 0.1 / sqrt(5) / 0.0349 m
    assert noisy == pytest.approx(np.sqrt(2) * 0.1 / np.sqrt(5) / np.radians(2.0), rel=0.15)


# ---------------------------------------------------------------------------- Waymo's own clock
def test_jittery_timestamps_keep_the_first_and_last_frames(tmp_path):
    write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])  # timestamps 0.09999 s apart
    rec = read_recording("waymo", tmp_path / "j.tfrecord")
    assert rec.dt == 0.1 and rec.frames == 91 and rec.duration == pytest.approx(8.9991)
    assert rec.frame_of(9.0) == 90 and rec.frame_of(0.0) == 0 and rec.frame_of(6.0) == 60
    assert rec.frame_of(0.05) == pytest.approx(0.05 / 0.09999)  # between frames: linear in time
    body = {"map": "replay", "episode_steps": 95,
            "replay": {"format": "waymo", "path": "j.tfrecord", "vehicles": ["2", "3", "4"]},
            "agents": [{"id": "ego", "mission": {"start": {"road": "road_401", "offset": 30.0}, "goal": {"endless": True}}}]}  # fmt: skip
    sim = build_simulation(load_scenario(_scenario(tmp_path, body)))
    sim.reset()
    assert _replayed(sim) == {"replay-2", "replay-3", "replay-4"}  # frame 0
    for _ in range(90):
        sim.step({"ego": np.zeros(3)})
    # t = 9.0 s is the last frame (recorded at 8.9991 s): every road user is still there, where recorded
    assert sim.time == pytest.approx(9.0) and _replayed(sim) == {"replay-2", "replay-3", "replay-4"}
    row = sim.table.row_of["replay-3"]
    assert sim.table.x[row] == pytest.approx(235.0 + 0.5 * 90)
    sim.step({"ego": np.zeros(3)})
    assert _replayed(sim) == set()  # and gone after it


def test_info_reports_the_nominal_frame_and_the_recorded_spacing(tmp_path, capsys):
    from smarts.__main__ import main

    write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    assert main(["replay", "info", str(tmp_path / "j.tfrecord"), "--format", "waymo", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frame_s"] == 0.1 and info["frames"] == 91 and info["frame_s_range"] == [0.09999, 0.09999]
    assert info["types"] == {"passenger": 2, "pedestrian": 1, "cyclist": 1} and info["ego"] == "1"
    assert info["map_marks"] == {"crosswalk": 1, "bike_lane": 1, "speed_bump": 1} and info["signals"] == 3


# ---------------------------------------------------------------------------- lane graphs
def test_partial_neighbours_change_lanes_only_where_they_run_alongside(tmp_path):
    m = compile_lane_map(read_recording("waymo", write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])).road_map)
    lane = m.lane_index_of
    # 102 (the turn pocket) runs beside 101's last 40 m only: 101 is cut there
    assert lane["101#2"] and m.lane_left[lane["101"]] == -1 and m.lane_left[lane["101#2"]] == lane["102"]
    assert m.lane_right[lane["102"]] == lane["101#2"] and m.lane_length[lane["101#2"]] == pytest.approx(40.0)
    assert m.road_ids[m.lane_road[lane["102"]]] == m.road_ids[m.lane_road[lane["101#2"]]]
    # straight on from 101 to the exit road is straight on, not a lane change into the pocket at its start
    route = [m.lane_ids[k] for k in shortest_route(m, lane["101"], lane["301"])]
    assert route == ["101", "101#2", "201", "301"]
    # and a take-over's route stays on the recorded track (y = 0)
    body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": 1}},
            "agents": [{"id": "ego", "action_space": "target_pose"}]}  # fmt: skip
    sim = build_simulation(load_scenario(_scenario(tmp_path, body)))
    mission = sim.missions[0]
    assert [m.lane_ids[k] for k in mission.route] == ["101", "101#2", "201", "301"]
    assert np.abs(mission.path_xy[:, 1]).max() < 0.5


def test_junction_lanes_are_marked_and_pair_only_with_junction_lanes(tmp_path):
    m = compile_lane_map(read_recording("waymo", write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])).road_map)
    internal = {m.lane_ids[k] for k in np.flatnonzero(m.lane_internal)}
    assert internal == {"201", "202", "203"}  # the dataset's interpolating lanes
    # a lane that crosses others mid-way is a junction lane even when the dataset does not say so

    def straight(x0, y0, x1, y1, n=11):
        return np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], axis=1)

    dm = DatasetMap(
        source="crossing", lane_ids=["a", "b", "c", "d"],
        polylines=[straight(0, 0, 40, 0), straight(20, -20, 20, 20), straight(40, 0, 90, 0), straight(0, 3.5, 40, 3.5)],
        widths=np.full(4, 3.5), speed_limits=np.full(4, 10.0), internal=np.zeros(4, dtype=bool),
        successors=[["c"], [], [], []], left=[[("d", 0, 10, 0, 10)], [], [], []], right=[[], [], [], [("a", 0, 10, 0, 10)]],
    )  # fmt: skip
    crossing = compile_lane_map(dm)
    marked = {crossing.lane_ids[k] for k in np.flatnonzero(crossing.lane_internal)}
    assert marked == {"a", "b", "d"} and crossing.lane_left[crossing.lane_index_of["a"]] == crossing.lane_index_of["d"]
    assert not crossing.lane_internal[crossing.lane_index_of["c"]]  # c only meets a end to end


def test_argoverse2_neighbours_of_different_lengths_are_cut_to_where_they_are_abreast(tmp_path):
    from tests.replay.files import av2_lane, av2_map

    data = av2_map()
    data["lane_segments"]["102"] = av2_lane(102, 40.0, 100.0, 3.5, [202], right=101)  # starts 40 m later
    rec = read_recording("argoverse2", write_av2(tmp_path / "scn", map_data=data))
    m = compile_lane_map(rec.road_map)
    lane = m.lane_index_of
    assert m.lane_left[lane["101"]] == -1 and m.lane_left[lane["101#2"]] == lane["102"]
    assert m.lane_length[lane["101"]] == pytest.approx(40.0)


# ---------------------------------------------------------------------------- signals
def test_recorded_signal_states_drive_the_simulators_signals(tmp_path):
    from smarts.env import DrivingParallelEnv

    write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": 1}},
            "agents": [{"id": "ego", "action_space": "relative_target_pose"}]}  # fmt: skip
    env = DrivingParallelEnv(str(_scenario(tmp_path, body)))
    try:
        obs, _ = env.reset(seed=0)
        m = env.sim.road_map
        assert m.tls_ids == ["signal_201", "signal_202", "signal_203"]
        via = env.sim.signals.via_colour
        colours = []
        for step in range(1, 60):
            obs, *_ = env.step({"ego": np.array([1.5, 0.0, 0.0], np.float32)})  # 15 m/s, as recorded
            colours.append((via[m.lane_index_of["201"]], via[m.lane_index_of["202"]], via[m.lane_index_of["203"]]))
            signal = obs["ego"]["signal"]  # the next signal on the route: 201's, until the ego enters it (x 200)
            if step <= 53:
                expected = RED if step < 50 else GREEN
                assert signal[expected - 1] == 1.0 and signal[:3].sum() == 1.0, (step, signal)
                assert signal[3] == pytest.approx(200.0 - 120.0 - 1.5 * step, abs=0.5)  # metres to the stop line
            else:
                assert signal.sum() == 0.0  # past it: no signal ahead
        assert colours[0] == (RED, RED, GREEN) and colours[48] == (RED, RED, GREEN)  # stop, arrow stop, go
        assert colours[49] == (GREEN, RED, GREEN)  # frame 50: 201 turns to go
    finally:
        env.close()


# ---------------------------------------------------------------------------- pedestrians and cyclists
def test_pedestrians_and_cyclists_replay_as_their_own_kinds(tmp_path):
    write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    rec = read_recording("waymo", tmp_path / "j.tfrecord")
    kinds = {vid: rec.kind_name(k) for k, vid in enumerate(rec.ids)}
    assert kinds == {"1": "passenger", "2": "passenger", "3": "cyclist", "4": "pedestrian"}
    assert rec.skipped == {"5": "an object of type other"} and rec.ego == "1"
    # each track keeps the median of its recorded box sizes (4.80, 4.82, 4.84, ... along the track)
    assert rec.length[rec.index_of["1"]] == pytest.approx(4.82) and rec.length[rec.index_of["4"]] == pytest.approx(0.52)
    body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": 1}},
            "agents": [{"id": "ego"}]}  # fmt: skip
    sim = build_simulation(load_scenario(_scenario(tmp_path, body)))
    sim.reset()
    t = sim.table
    walker, rider = t.row_of["replay-4"], t.row_of["replay-3"]
    assert t.role[walker] == Role.PEDESTRIAN and t.vtype[walker] == VehicleType.PEDESTRIAN
    assert t.role[rider] == Role.REPLAY and t.vtype[rider] == VehicleType.BICYCLE  # a cyclist, its own type
    assert (t.length[rider], t.width[rider]) == pytest.approx((1.82, 0.7))


def test_a_recorded_pedestrian_is_seen_and_hit_like_any_road_user(tmp_path):
    from smarts.env import DrivingParallelEnv

    write_waymo(tmp_path / "j.tfrecord", [waymo_junction(pedestrian_at=(150.0, 0.0))])  # standing in lane 101
    body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": 1}},
            "agents": [{"id": "ego", "action_space": "relative_target_pose"}]}  # fmt: skip
    env = DrivingParallelEnv(str(_scenario(tmp_path, body)))
    try:
        obs, _ = env.reset(seed=0)
        flagged = 0
        for step in range(1, 40):
            obs, _, terminations, _, _ = env.step({"ego": np.array([1.5, 0.0, 0.0], np.float32)})
            neighbours = obs["ego"]["neighbours"]
            flagged = max(flagged, int((neighbours[:, 8] == 1.0).sum()))
            if terminations["ego"]:
                break
        # front at 120 + 2.41 + 1.5 t meets the pedestrian's box (149.75) after about 18 steps
        assert terminations["ego"] and env.sim.agent_events[0, Event.COLLISION] and 16 <= step <= 20
        assert flagged == 1  # seen as a pedestrian in the observation before
    finally:
        env.close()


def test_a_pedestrian_cannot_be_taken_over(tmp_path):
    write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])
    for vid, what in (("4", "is a pedestrian, not a vehicle"), ("3", "is a cyclist, not a vehicle"),
                      ("5", "is an object of type other, which is not replayed")):  # fmt: skip
        body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": vid}},
                "agents": [{"id": "ego"}]}  # fmt: skip
        with pytest.raises(ScenarioError, match=rf"replay.take_over.ego: '{vid}' in .* {what}; an agent takes over a "
                                                r"vehicle \(vehicles: 1, 2 \(2 in all\)\)"):  # fmt: skip
            build_simulation(load_scenario(_scenario(tmp_path, body)))


# ---------------------------------------------------------------------------- marks on the map
def test_crosswalks_bike_lanes_and_speed_bumps_are_in_the_road_map(tmp_path):
    m = compile_lane_map(read_recording("waymo", write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])).road_map)
    assert (
        len(m.marks(MARK_CROSSWALK)) == 1 and len(m.marks(MARK_BIKE_LANE)) == 1 and len(m.marks(MARK_SPEED_BUMP)) == 1
    )
    cross = m.marks(MARK_CROSSWALK)[0]
    assert cross[:, 0].min() == 238.0 and cross[:, 0].max() == 242.0
    assert "501" not in m.lane_index_of  # the bike lane is a mark, not a lane cars drive
    m.save(tmp_path / "map.npz")
    again = RoadMap.load(tmp_path / "map.npz")
    np.testing.assert_array_equal(again.mark_points, m.mark_points)
    assert again.mark_kind.tolist() == m.mark_kind.tolist()
    rec = read_recording(
        "argoverse2", write_av2(tmp_path / "scn", map_data=av2_map_with_crossings(drivable_as_list=True))
    )
    av2 = compile_lane_map(rec.road_map)
    assert len(av2.marks(MARK_CROSSWALK)) == 1 and len(av2.marks(MARK_BIKE_LANE)) == 1
    assert "901" not in av2.lane_index_of and len(av2.junction_shapes) == 1  # the drivable area, given as a list


def test_a_map_saved_before_marks_existed_still_loads(tmp_path):
    from smarts.maps.road_map import CHECKSUM_KEY, arrays_sha256

    m = compile_lane_map(read_recording("argoverse2", write_av2(tmp_path / "scn")).road_map)
    arrays = {k: v for k, v in m.to_arrays().items() if not k.startswith("mark_")}
    arrays[CHECKSUM_KEY] = np.array(arrays_sha256(arrays))
    np.savez(tmp_path / "old.npz", **arrays)
    old = RoadMap.load(tmp_path / "old.npz")
    assert old.mark_kind.size == 0 and old.mark_offsets.tolist() == [0] and old.lane_ids == m.lane_ids


# ---------------------------------------------------------------------------- non-finite values
def test_a_nan_in_a_parquet_column_names_the_file_column_and_row(tmp_path):
    rows = av2_tracks()
    k = next(i for i, r in enumerate(rows) if r["track_id"] == "11" and r["timestep"] == 30)
    rows[k]["position_x"] = float("nan")
    with pytest.raises(ReplayError, match=rf"scenario_{AV2_ID}.parquet: column position_x: expected a finite number, "
                                          rf"got nan in row {k + 1}$"):  # fmt: skip
        read_recording("argoverse2", write_av2(tmp_path / "a", tracks=rows))
    rows = av2_tracks()
    rows[3]["heading"] = float("inf")
    with pytest.raises(ReplayError, match=r"column heading: expected a finite number, got inf in row 4$"):
        read_recording("argoverse2", write_av2(tmp_path / "b", tracks=rows))
    rows = av2_tracks()
    rows[5]["velocity_y"] = 1e6
    with pytest.raises(ReplayError, match=r"column velocity_y: expected a value within \+-200, got 1e\+06 in row 6$"):
        read_recording("argoverse2", write_av2(tmp_path / "c", tracks=rows))


def test_a_non_finite_ngsim_value_names_the_file_column_and_row(tmp_path):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    lines = path.read_text().splitlines()
    for column, value in (("Local_X", "inf"), ("Local_Y", "nan"), ("v_Width", "-inf"), ("v_Length", "0")):
        cells = lines[70].split(",")  # vehicle 2, not the one taken over
        cells[NGSIM_HEADER.index(column)] = value
        bad = tmp_path / f"bad_{column}.csv"
        bad.write_text("\n".join([*lines[:70], ",".join(cells), *lines[71:]]) + "\n")
        expected = "a positive size" if value in ("-inf", "0") and column.startswith("v_") else "a finite number"
        expected = "a finite number" if value == "-inf" else expected
        with pytest.raises(ReplayError, match=rf"bad_{column}.csv: column {column}: expected {expected}, got "
                                              rf"{value} in data row 70$"):  # fmt: skip
            read_recording("ngsim", bad)


def test_a_non_finite_waymo_state_names_the_track_state_and_field(tmp_path):
    msg = waymo_junction()
    msg.tracks[1].states[7].heading = float("nan")
    with pytest.raises(ReplayError, match=rf"\(scenario {JUNCTION_ID}\): tracks\[1\].states\[7\].heading: expected a "
                                          r"finite number, got nan"):  # fmt: skip
        read_recording("waymo", write_waymo(tmp_path / "a.tfrecord", [msg]))
    msg = waymo_junction()
    msg.tracks[0].states[3].length = 0.0
    with pytest.raises(ReplayError, match=r"tracks\[0\].states\[3\].length: expected a positive size, got 0"):
        read_recording("waymo", write_waymo(tmp_path / "b.tfrecord", [msg]))
    msg = waymo_junction()
    msg.map_features[0].lane.polyline[2].x = float("inf")
    with pytest.raises(ReplayError, match=r"map_features \(id 101\).lane.polyline\[2\]: expected a finite position"):
        read_recording("waymo", write_waymo(tmp_path / "c.tfrecord", [msg]))


# ---------------------------------------------------------------------------- the wrong file
def test_the_wrong_file_is_one_clear_line(tmp_path):
    write_av2(tmp_path / "scn")
    parquet = tmp_path / "scn" / f"scenario_{AV2_ID}.parquet"
    cases = [
        ("waymo", tmp_path, "is a folder; --format waymo reads a TFRecord file of Scenario records (name the file)"),
        ("ngsim", tmp_path, "is a folder; --format ngsim reads an NGSIM trajectory file (.csv or .txt)"),
        ("ngsim", parquet, "is a parquet file (Argoverse 2 scenarios are read with --format argoverse2), not an NGSIM"),
        ("waymo", parquet, "is a parquet file (Argoverse 2 scenarios are read with --format argoverse2), not a waymo"),
    ]
    write_waymo(tmp_path / "w.tfrecord", [waymo_junction()])
    cases.append(("ngsim", tmp_path / "w.tfrecord", "is a TFRecord file (Waymo Open Motion scenarios are read with "
                                                    "--format waymo), not an NGSIM trajectory file"))  # fmt: skip
    cases.append(("argoverse2", tmp_path / "w.tfrecord", "is a tfrecord file, not an Argoverse 2 scenario parquet"))
    for fmt, path, message in cases:
        with pytest.raises(ReplayError) as err:
            read_recording(fmt, path)
        text = str(err.value)
        assert text.startswith(f"{path}: ") and message in text and "\n" not in text, text


def test_tf_example_records_say_that_scenario_files_are_needed(tmp_path):
    from smarts.replay.tfrecord import write_records

    # a tf.train.Example: features {feature {key: "state/current/x" value {float_list {value: 1.0}}}}
    value = b"\x12\x06\x0a\x04\x00\x00\x80\x3f"  # Feature.float_list (2) {value (1) packed: 1.0f}
    key = b"state/current/x"
    entry = b"\x0a" + bytes([len(key)]) + key + b"\x12" + bytes([len(value)]) + value
    features = b"\x0a" + bytes([len(entry)]) + entry
    example = b"\x0a" + bytes([len(features)]) + features
    write_records(tmp_path / "training_tfexample.tfrecord", [example])
    with pytest.raises(ReplayError, match=r"training_tfexample.tfrecord: holds tf.Example records \(the motion "
                                          r"dataset's tf_example files\); replay reads its Scenario files"):  # fmt: skip
        read_recording("waymo", tmp_path / "training_tfexample.tfrecord")


def test_taking_over_a_vehicle_that_ends_off_the_map_names_the_entry_with_plain_numbers(tmp_path):
    rows = av2_tracks()
    for r in rows:  # vehicle 11 drives on past the map's end (x 200) to x 451.36
        if r["track_id"] == "11":
            r["position_x"] = 30.0 + (451.36 - 30.0) * (r["timestep"] - 20) / 59
    write_av2(tmp_path / "scn", tracks=rows)
    body = {"map": "replay", "replay": {"format": "argoverse2", "path": "scn", "take_over": {"ego": "11"}},
            "agents": [{"id": "AV-driver"}, {"id": "ego"}]}  # fmt: skip
    body["replay"]["take_over"]["AV-driver"] = "AV"
    with pytest.raises(MapError) as err:
        build_simulation(load_scenario(_scenario(tmp_path, body)))
    text = str(err.value)
    assert "replay.take_over.ego: vehicle '11' ends at (451.4, 5.2), which is off the map" in text
    assert "np.float64" not in text and "agents[1]" not in text


def test_frame_ranges_are_checked_before_anything_is_allocated():
    from smarts.replay.recording import MAX_FRAMES, from_samples

    def rec(ids, frames):
        n = len(ids)
        return from_samples("mem.csv", "test", np.array(ids), np.array(frames), np.arange(n, dtype=float), np.zeros(n),
                            None, None, np.full(n, 4.0), np.full(n, 2.0), np.zeros(n, np.int8), 0.1)  # fmt: skip

    # one vehicle whose frames jump by 2**40 (a 1 TiB fill before the check)
    with pytest.raises(ReplayError, match=r"mem.csv: vehicle 'a' has no samples from frame 1 to frame 1099511627777"):
        rec(["a", "a", "a"], [0, 1, 2**40 + 1])
    # two vehicles a billion frames apart: the recording's span
    with pytest.raises(ReplayError, match=rf"mem.csv: frames run from 0 to 1000000001 \(1000000002 frames\); at most "
                                          rf"{MAX_FRAMES} are supported"):  # fmt: skip
        rec(["a", "a", "b", "b"], [0, 1, 10**9, 10**9 + 1])
    assert rec(["a", "a", "a"], [0, 1, 90]).count.tolist() == [91]  # a gap of up to 10 s is filled


def test_a_recorded_pedestrian_hides_behind_a_recorded_vehicle(tmp_path):
    from smarts.env import DrivingParallelEnv

    # the pedestrian stands at (200, 4); vehicle 2 waits in the pocket at (190, 3.7), between it and
    # the ego (coming along y = 0) until the ego is close to the pocket
    write_waymo(tmp_path / "j.tfrecord", [waymo_junction(pedestrian_at=(200.0, 4.0))])
    seen = {}
    for occlusion in (False, True):
        agent = {"id": "ego", "action_space": "relative_target_pose",
                 "interface": {"occlusion": {"enabled": occlusion}}}  # fmt: skip
        body = {"map": "replay", "replay": {"format": "waymo", "path": "j.tfrecord", "take_over": {"ego": 1}},
                "agents": [agent]}  # fmt: skip
        env = DrivingParallelEnv(str(_scenario(tmp_path, body)))
        try:
            env.reset(seed=0)
            flags = []
            for _ in range(45):
                obs, *_ = env.step({"ego": np.array([1.5, 0.0, 0.0], np.float32)})
                flags.append(int((obs["ego"]["neighbours"][:, 8] == 1.0).sum()))
            seen[occlusion] = flags
        finally:
            env.close()
    assert seen[False][27] == 1 and seen[True][27] == 0  # ego at x 162: the waiting car hides the pedestrian
    assert seen[True][44] == 1  # ego at x 187.5, beside the car: in view again


def test_the_viewer_scene_shows_the_recorded_signals_and_a_bad_drivable_area_is_named(tmp_path):
    from smarts.viz.scene import map_scene

    m = compile_lane_map(read_recording("waymo", write_waymo(tmp_path / "j.tfrecord", [waymo_junction()])).road_map)
    signals = map_scene(m)["signals"]
    assert sorted({s["tls"] for s in signals}) == ["signal_201", "signal_202", "signal_203"]
    assert {(m.lane_ids[s["from_lane"]], m.lane_ids[s["via_lane"]]) for s in signals} == {
        ("101#2", "201"), ("102", "202"), ("102", "203")}  # fmt: skip
    assert all(s["stop"] == [200.0, 0.0] or s["stop"] == [200.0, 3.7] for s in signals)
    from tests.replay.files import av2_map

    data = av2_map()
    data["drivable_areas"] = "everywhere"
    with pytest.raises(ReplayError, match=r"log_map_archive_.*\.json: drivable_areas: expected a mapping of id -> "
                                          r"entry \(or a list of entries\), got str"):  # fmt: skip
        read_recording("argoverse2", write_av2(tmp_path / "scn", map_data=data))
