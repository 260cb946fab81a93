"""NGSIM replay end to end: a CSV in the published layout, the built-in straight_2lane map, the
replay provider in a real simulation (positions, entries and exits, take-over, reactive hand-over)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from smarts.core.errors import ReplayError, ScenarioError
from smarts.core.vehicle_table import Role, VehicleType
from smarts.env.assembly import build_simulation
from smarts.replay import read_recording
from smarts.scenario import load_scenario, read_scenario, scenario_to_dict
from tests.replay.files import FEET, GLOBAL_SHIFT, LANE0_Y, NGSIM_HEADER, straight, three_vehicles, write_ngsim

ALIGN = {"swap_xy": True, "flip_y": True}


def scenario(tmp_path: Path, replay: dict, agents: list | None = None, **extra) -> Path:
    data = {
        "map": "builtin:straight_2lane",
        "episode_steps": 200,
        "replay": {"format": "ngsim", "path": "traj.csv", **ALIGN, **replay},
        "agents": agents
        or [
            {"id": "ego", "mission": {"start": {"road": "main", "lane": 1, "offset": 250.0}, "goal": {"endless": True}}}
        ],
        **extra,
    }
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def csv_file(tmp_path) -> Path:
    return write_ngsim(tmp_path / "traj.csv", three_vehicles())


def _stand_still(sim) -> dict:
    return {a: np.zeros(3) for a in sim.agent_ids}


def _positions(sim) -> dict[str, tuple[float, float, float, float]]:
    t = sim.table
    return {t.ids[r]: (t.x[r], t.y[r], t.heading[r], t.speed[r]) for r in t.rows_owned_by(1)}


# ---------------------------------------------------------------------------- the reader
def test_reader_converts_feet_to_metres_and_front_to_centre(csv_file):
    rec = read_recording("ngsim", csv_file, **ALIGN)
    expected = three_vehicles()
    assert rec.ids == ["1", "2", "3"] and rec.dt == pytest.approx(0.1)
    assert rec.first.tolist() == [100, 110, 130] and rec.count.tolist() == [60, 80, 20]
    for k, vid in enumerate(rec.ids):
        track = rec.track(k)
        np.testing.assert_allclose(track[:, 0], expected[vid]["x"], atol=0.01)  # box centre, metres
        np.testing.assert_allclose(track[:, 1], expected[vid]["y"], atol=0.01)
        np.testing.assert_allclose(track[:, 2], 0.0, atol=1e-6)
    np.testing.assert_allclose(rec.length, [4.5, 12.0, 4.5], atol=1e-4)
    np.testing.assert_allclose(rec.width, [1.8, 2.5, 1.8], atol=1e-4)
    np.testing.assert_allclose(rec.track(0)[:, 3], 10.0, atol=1e-3)  # from positions, m/s
    np.testing.assert_allclose(rec.track(1)[:, 3], 12.0, atol=1e-3)
    assert rec.vtype.tolist() == [VehicleType.PASSENGER, VehicleType.TRUCK, VehicleType.PASSENGER]
    assert rec.duration == pytest.approx(8.9) and rec.frames == 90


def test_coordinate_options(csv_file):
    plain = read_recording("ngsim", csv_file)  # identity: x = Local_X, y = Local_Y
    local_x, local_y = -LANE0_Y, 20.0 + 2.25  # vehicle 1's first front point, metres
    # heading along +y (Local_Y grows), so the centre is half a length behind the front
    assert plain.track(0)[0, :3] == pytest.approx([local_x, local_y - 2.25, np.pi / 2], abs=0.01)
    flipped = read_recording("ngsim", csv_file, flip_y=True)
    assert flipped.track(0)[0, :3] == pytest.approx([local_x, -local_y + 2.25, -np.pi / 2], abs=0.01)
    swapped = read_recording("ngsim", csv_file, swap_xy=True)
    assert swapped.track(0)[0, :3] == pytest.approx([local_y - 2.25, local_x, 0.0], abs=0.01)
    moved = read_recording("ngsim", csv_file, **ALIGN, offset=(5.0, -2.0))
    assert moved.track(0)[0, :2] == pytest.approx([20.0 + 5.0, LANE0_Y - 2.0], abs=0.01)
    glob = read_recording(
        "ngsim", csv_file, coordinates="global", **ALIGN, offset=(-GLOBAL_SHIFT[1] * FEET, GLOBAL_SHIFT[0] * FEET)
    )
    assert glob.track(0)[0, :2] == pytest.approx([20.0, LANE0_Y], abs=0.01)


def test_noisy_positions_give_smooth_heading_and_speed(tmp_path):
    rng = np.random.default_rng(0)
    v = straight(0, 80, 10.0, 15.0, LANE0_Y)
    v["y"] = v["y"] + rng.normal(0.0, 0.08, 80)  # NGSIM-like lateral jitter
    v["x"] = v["x"] + rng.normal(0.0, 0.08, 80)
    rec = read_recording("ngsim", write_ngsim(tmp_path / "traj.csv", {"7": v}), **ALIGN)
    track = rec.track(0)
    raw_heading = np.arctan2(np.diff(v["y"]), np.diff(v["x"]))
    assert np.abs(track[5:-5, 2]).max() < 0.5 * np.abs(raw_heading).max()
    assert (
        np.abs(track[5:-5, 3] - 15.0).max()
        < 0.5 * np.abs(np.hypot(np.diff(v["x"]), np.diff(v["y"])) / 0.1 - 15.0).max()
    )


def test_missing_columns_name_the_file_and_columns(tmp_path):
    header = [h for h in NGSIM_HEADER if h not in ("Local_Y", "v_Width")]
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles(), header=header)
    with pytest.raises(ReplayError) as err:
        read_recording("ngsim", path)
    assert str(path) in str(err.value) and "Local_Y" in str(err.value) and "v_Width" in str(err.value)
    # global coordinates need the other pair
    path2 = write_ngsim(tmp_path / "traj2.csv", three_vehicles(), header=[h for h in NGSIM_HEADER if h != "Global_X"])
    read_recording("ngsim", path2)
    with pytest.raises(ReplayError, match="Global_X"):
        read_recording("ngsim", path2, coordinates="global")


def test_bad_values_name_the_file_and_column(tmp_path):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[NGSIM_HEADER.index("Local_X")] = "abc"
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ReplayError) as err:
        read_recording("ngsim", path)
    assert str(path) in str(err.value) and "column Local_X: expected a number, got 'abc' in data row 3" in str(
        err.value
    )
    with pytest.raises(ReplayError, match="does not exist"):
        read_recording("ngsim", tmp_path / "nothing.csv")


def test_two_samples_of_one_vehicle_in_one_frame_are_refused(tmp_path):
    path = write_ngsim(tmp_path / "traj.csv", three_vehicles())
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines + [lines[5]]) + "\n")
    with pytest.raises(ReplayError, match=r"vehicle '1' has two samples at frame 104"):
        read_recording("ngsim", path)


# ---------------------------------------------------------------------------- the provider
def test_replayed_positions_match_the_recording_and_vehicles_enter_and_leave_on_time(tmp_path, csv_file):
    sim = build_simulation(load_scenario(scenario(tmp_path, {})))
    sim.reset()
    tracks = three_vehicles()
    entered, left = {}, {}
    seen: set[str] = set()
    for step in range(0, 100):
        if step:
            sim.step(_stand_still(sim))
        now = _positions(sim)
        frame = 100 + step  # the recording starts at frame 100 (t = 0)
        for vid, v in tracks.items():
            k = frame - v["first"]
            key = f"replay-{vid}"
            if 0 <= k < len(v["x"]):
                assert key in now, (step, vid)
                x, y, heading, speed = now[key]
                assert abs(x - v["x"][k]) < 0.01 and abs(y - v["y"][k]) < 0.01, (step, vid)
                assert abs(heading) < 1e-6
                entered.setdefault(vid, step)
            else:
                assert key not in now, (step, vid)
                if vid in entered:
                    left.setdefault(vid, step)
        seen |= set(now)
    assert entered == {"1": 0, "2": 10, "3": 30}
    assert left == {"1": 60, "3": 50, "2": 90}  # each leaves the step after its last frame
    t = sim.table
    assert all(t.role[t.row_of[k]] == Role.REPLAY for k in _positions(sim))


def test_replay_moves_between_frames_when_the_step_is_shorter(tmp_path, csv_file):
    sim = build_simulation(load_scenario(scenario(tmp_path, {}, step_length=0.05)))
    sim.reset()
    for _ in range(5):
        sim.step(_stand_still(sim))
    x, y, _, speed = _positions(sim)["replay-1"]
    assert x == pytest.approx(20.0 + 10.0 * 0.25, abs=0.01) and y == pytest.approx(LANE0_Y, abs=0.01)
    assert speed == pytest.approx(10.0, abs=0.01)


def test_window_start_duration_and_vehicle_filter(tmp_path, csv_file):
    sim = build_simulation(load_scenario(scenario(tmp_path, {"start": 3.0, "duration": 2.0, "vehicles": ["1", 3]})))
    sim.reset()
    now = _positions(sim)
    assert set(now) == {"replay-1", "replay-3"}  # at frame 130; vehicle 2 is filtered out
    assert now["replay-3"][0] == pytest.approx(100.0, abs=0.01) and now["replay-1"][0] == pytest.approx(50.0, abs=0.01)
    for _ in range(20):
        sim.step(_stand_still(sim))
    assert set(_positions(sim)) == {"replay-1"}  # frame 150: vehicle 3 has left
    sim.step(_stand_still(sim))
    assert _positions(sim) == {}  # the window (2 s) is over


def test_replay_is_deterministic_across_resets(tmp_path, csv_file):
    sim = build_simulation(load_scenario(scenario(tmp_path, {})))
    runs = []
    for _ in range(2):
        sim.reset()
        trace = []
        for _ in range(40):
            sim.step(_stand_still(sim))
            trace.append(sorted(_positions(sim).items()))
        runs.append(trace)
    assert runs[0] == runs[1]


def test_an_agent_collides_with_a_replayed_vehicle(tmp_path, csv_file):
    agents = [
        {"id": "ego", "mission": {"start": {"road": "main", "lane": 0, "offset": 60.0}, "goal": {"endless": True}}}
    ]
    sim = build_simulation(load_scenario(scenario(tmp_path, {}, agents=agents)))
    sim.reset()
    from smarts.core.events import Event

    for step in range(60):
        sim.step(_stand_still(sim))
        if sim.agent_events[0, Event.COLLISION]:
            break
    # vehicle 1 (front at 20 + 2.25 + 10 t) reaches the standing agent's rear (60 - 2.3) near t = 3.5 s
    assert sim.agent_events[0, Event.COLLISION] and 30 <= step <= 40


# ---------------------------------------------------------------------------- take-over
def test_take_over_starts_in_the_vehicle_and_aims_at_its_last_position(tmp_path, csv_file):
    path = scenario(tmp_path, {"take_over": {"ego": 2}}, agents=[{"id": "ego", "action_space": "target_pose"}])
    spec = load_scenario(path)
    sim = build_simulation(spec)
    sim.reset()
    row = int(sim.agent_row[0])
    t = sim.table
    v = three_vehicles()["2"]
    # the episode starts when vehicle 2 enters (1 s into the recording): vehicle 1 is already there
    assert t.ids[row] == "replay-2" and t.owner[row] == 0 and t.role[row] == Role.AGENT
    assert (t.x[row], t.y[row]) == pytest.approx((v["x"][0], v["y"][0]), abs=0.01)
    assert t.speed[row] == pytest.approx(12.0, abs=0.01) and t.heading[row] == pytest.approx(0.0, abs=1e-6)
    assert t.length[row] == pytest.approx(12.0, abs=1e-3) and t.vtype[row] == VehicleType.TRUCK
    mission = sim.missions[0]
    assert mission.goal_xy == pytest.approx([v["x"][-1], v["y"][-1]], abs=0.01)
    assert set(_positions(sim)) == {"replay-1"}
    # the agent drives: the recording no longer moves its vehicle
    for _ in range(5):
        sim.step({"ego": np.array([t.x[row], t.y[row], 0.0])})  # hold position
    assert t.x[row] < v["x"][5] - 0.5  # braking, where the recorded truck drove on at 12 m/s
    assert "replay-2" not in _positions(sim)
    # written back, the scenario reads the same
    assert read_scenario(scenario_to_dict(spec), base_dir=tmp_path) == spec


def test_take_over_errors_name_the_file_and_field(tmp_path, csv_file):
    path = scenario(tmp_path, {"take_over": {"ego": "99"}}, agents=[{"id": "ego"}])
    with pytest.raises(ScenarioError) as err:
        build_simulation(load_scenario(path))
    message = str(err.value)
    assert str(path) in message and "replay.take_over.ego" in message and "'99'" in message and "traj.csv" in message
    path = scenario(tmp_path, {"take_over": {"ego": "3"}, "start": 0.0}, agents=[{"id": "ego"}])
    with pytest.raises(ScenarioError, match=r"replay.take_over.ego: vehicle '3' is recorded from 3 s to 4.9 s"):
        build_simulation(load_scenario(path))
    path = scenario(tmp_path, {"vehicles": ["1", "42"]})
    with pytest.raises(ScenarioError, match=r"replay.vehicles: no vehicle\(s\) '42'"):
        build_simulation(load_scenario(path))


def test_scenario_file_checks_of_the_replay_section(tmp_path, csv_file):
    with pytest.raises(ScenarioError, match=r"replay.take_over.other: unknown agent 'other'"):
        load_scenario(scenario(tmp_path, {"take_over": {"other": "1"}}))
    with pytest.raises(ScenarioError, match=r"agents\[0\].mission: required field missing"):
        load_scenario(scenario(tmp_path, {}, agents=[{"id": "ego"}]))
    with pytest.raises(ScenarioError, match=r"agents\[0\].mission: not allowed"):
        load_scenario(scenario(tmp_path, {"take_over": {"ego": "1"}}))
    with pytest.raises(ScenarioError, match=r"replay.format: .*ngsim"):
        load_scenario(scenario(tmp_path, {"format": "highd"}))
    with pytest.raises(ScenarioError, match=r"replay.reactive: "):
        load_scenario(scenario(tmp_path, {"reactive": "sometimes"}))
    with pytest.raises(ScenarioError, match=r"map: 'replay' is the map of an argoverse2 or waymo replay"):
        load_scenario(scenario(tmp_path, {}, map="replay"))
    missing = scenario(tmp_path, {"path": "gone.csv"})
    with pytest.raises(ReplayError) as err:
        build_simulation(load_scenario(missing))
    assert str(missing) in str(err.value) and "replay.path" in str(err.value) and "gone.csv" in str(err.value)


# ---------------------------------------------------------------------------- reactive hand-over
def test_reactive_vehicle_switches_to_traffic_keeping_its_state(tmp_path, csv_file):
    # the agent stands in lane 0 at 60 m; vehicle 1 comes up behind it in the same lane
    agents = [
        {"id": "ego", "mission": {"start": {"road": "main", "lane": 0, "offset": 60.0}, "goal": {"endless": True}}}
    ]
    path = scenario(tmp_path, {"reactive": "interaction", "reactive_distance": 15.0}, agents=agents)
    sim = build_simulation(load_scenario(path))
    replay = sim.providers[1]
    traffic = sim.providers[2]
    assert replay.name == "replay" and traffic.name != "replay"
    sim.reset()
    t = sim.table
    before = None
    for step in range(1, 60):
        row = t.row_of.get("replay-1")
        state = None if row is None else (t.x[row], t.y[row], t.heading[row], t.speed[row])
        sim.step(_stand_still(sim))
        if replay.handed_over:
            before = state
            break
    assert replay.handed_over == ["replay-1"] and before is not None
    # handed over when its centre came within 15 m of the agent's (at 60 m): from x = 45 m
    assert before[0] == pytest.approx(45.0, abs=1.01)
    row = t.row_of["replay-1"]
    assert t.owner[row] == traffic.provider_id and t.role[row] == Role.TRAFFIC
    # the traffic model drove on from the recorded pose: one step at about the recorded speed
    assert t.x[row] - before[0] == pytest.approx(before[3] * 0.1, abs=0.05)
    assert t.y[row] == pytest.approx(before[1], abs=0.05) and t.heading[row] == pytest.approx(before[2], abs=0.02)
    assert abs(t.speed[row] - before[3]) <= 1.0  # within a step of braking
    # and it reacts: it stops behind the standing agent instead of running through it
    from smarts.core.events import Event

    for _ in range(80):
        sim.step(_stand_still(sim))
        assert not sim.agent_events[0, Event.COLLISION]
    assert t.x[row] < 60.0 - 4.5 and t.speed[row] < 0.5
    # vehicle 3 enters 40 m ahead of the agent and drives away: replayed to the end of its track
    assert "replay-3" not in replay.handed_over


def test_hand_over_itself_keeps_position_heading_and_speed(tmp_path, csv_file):
    path = scenario(tmp_path, {"reactive": "interaction"})
    sim = build_simulation(load_scenario(path))
    replay, traffic = sim.providers[1], sim.providers[2]
    sim.reset()
    for _ in range(15):
        sim.step(_stand_still(sim))
    t = sim.table
    rows = np.array([t.row_of["replay-1"], t.row_of["replay-2"]])
    state = t.data[:, rows].copy()
    replay._hand_to_traffic(sim, rows)
    assert t.owner[rows].tolist() == [traffic.provider_id] * 2
    np.testing.assert_array_equal(t.data[:, rows], state)


def test_always_reactive_hands_every_vehicle_over_as_it_enters(tmp_path, csv_file):
    sim = build_simulation(load_scenario(scenario(tmp_path, {"reactive": "always"})))
    replay = sim.providers[1]
    sim.reset()
    assert replay.handed_over == ["replay-1"]
    for _ in range(35):
        sim.step(_stand_still(sim))
    assert replay.handed_over == ["replay-1", "replay-2", "replay-3"]
    t = sim.table
    assert all(t.role[r] == Role.TRAFFIC for r in t.alive_rows if t.ids[r].startswith("replay-"))


# ---------------------------------------------------------------------------- env and validate
def test_replayed_vehicles_are_neighbours_in_the_agents_observation(tmp_path, csv_file):
    from smarts.env import DrivingParallelEnv

    agents = [
        {"id": "ego", "mission": {"start": {"road": "main", "lane": 1, "offset": 40.0}, "goal": {"endless": True}}}
    ]
    env = DrivingParallelEnv(str(scenario(tmp_path, {"vehicles": ["1"]}, agents=agents)))
    try:
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            obs, *_ = env.step({"ego": np.zeros(3, np.float32)})
        neighbours = obs["ego"]["neighbours"]
        # vehicle 1 at 25 m in lane 0 (3.2 m to the right), 15 m behind the agent at 40 m
        assert env.observation_space("ego").contains(obs["ego"])
        rows = neighbours[np.abs(neighbours).sum(axis=1) > 0]
        assert len(rows) == 1
    finally:
        env.close()


def test_scenario_validate_checks_the_replay_section(tmp_path, csv_file):
    import subprocess
    import sys

    good = scenario(tmp_path, {"take_over": {"ego": "2"}}, agents=[{"id": "ego"}])
    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text().replace("ego: '2'", "ego: '77'"))
    done = subprocess.run([sys.executable, "-m", "smarts", "scenario", "validate", str(good), str(bad)],
                          capture_output=True, text=True, check=False)  # fmt: skip
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"{good}: valid" in done.stdout
    assert f"{bad}: replay.take_over.ego: no vehicle '77' in" in done.stdout + done.stderr


def test_reactive_vehicles_go_to_sumo_when_sumo_drives_the_traffic(tmp_path, csv_file):
    agents = [
        {"id": "ego", "mission": {"start": {"road": "main", "lane": 0, "offset": 60.0}, "goal": {"endless": True}}}
    ]
    path = scenario(tmp_path, {"reactive": "interaction", "reactive_distance": 15.0}, agents=agents,
                    traffic={"engine": "sumo"})  # fmt: skip
    sim = build_simulation(load_scenario(path))
    try:
        replay, sumo = sim.providers[1], sim.providers[2]
        assert sumo.name != "replay" and type(sumo).__name__ == "SumoTrafficProvider"
        sim.reset()
        from smarts.core.events import Event

        for _ in range(100):
            sim.step(_stand_still(sim))
            assert not sim.agent_events[0, Event.COLLISION]
        assert replay.handed_over[0] == "replay-1"
        assert sim.table.owner[sim.table.row_of["replay-1"]] == sumo.provider_id
    finally:
        sim.close()


def test_the_combined_file_of_several_sites_is_named_as_such(tmp_path):
    import csv

    rows = list(csv.reader(write_ngsim(tmp_path / "one.csv", three_vehicles()).read_text().splitlines()))
    path = tmp_path / "all.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([*rows[0], "Location"])
        for site in ("i-80", "us-101"):
            w.writerows([*r, site] for r in rows[1:])
    with pytest.raises(ReplayError, match=r"all.csv: the file holds several NGSIM sites \(column Location: i-80, "
                                          r"us-101\), whose vehicle ids repeat: choose one with replay.scenario "
                                          r"\(--location\)"):  # fmt: skip
        read_recording("ngsim", path)
    one = read_recording("ngsim", path, scenario="US-101", swap_xy=True, flip_y=True)
    assert one.ids == ["1", "2", "3"] and one.count.tolist() == [60, 80, 20]
    with pytest.raises(ReplayError, match=r"all.csv: location 'peachtree': no rows of that site \(column Location: "
                                          r"i-80, us-101\)"):  # fmt: skip
        read_recording("ngsim", path, scenario="peachtree")
