"""`python -m smarts.diagnostic --batched` on a tiny budget: rows, JSON, bad flags."""

import json
import subprocess
import sys
from pathlib import Path

from smarts.scenario import map_path


def test_batched_rows_are_written_as_json(tmp_path):
    out = tmp_path / "batched.json"
    done = subprocess.run(
        [sys.executable, "-m", "smarts.diagnostic", "--batched", "--batches", "1,4", "--cases", "free_direct,lead_lane,mix_lane",
         "--steps", "10", "--warmup", "2", "--per-env-agent-steps", "20", "--sensor-batch", "2", "--sensor-breakdown",
         "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    rows = json.loads(out.read_text())["rows"]
    assert [(r["case"], r["batch"]) for r in rows] == [
        ("free_direct", 1), ("free_direct", 4), ("lead_lane", 1), ("lead_lane", 4), ("mix_lane", 1), ("mix_lane", 4),
    ]  # fmt: skip
    for r in rows:
        assert r["agent_steps_per_s"] > 0 and r["per_env_agent_steps_per_s"] > 0 and r["memory_per_episode_kb"] > 0
        assert r["speedup"] == r["agent_steps_per_s"] / r["per_env_agent_steps_per_s"]
    assert "speed-up" in done.stdout
    sensors = json.loads(out.read_text())["sensors"]
    assert [(r["case"], r["batch"], r["agents"], r["vehicles"]) for r in sensors] == [
        ("sensors_v2v", 2, 10, 50),
        ("sensors_off", 2, 10, 50),
    ]
    assert sensors[0]["ratio_to_off"] == sensors[0]["agent_steps_per_s"] / sensors[1]["agent_steps_per_s"]
    assert "All sensors and V2V" in done.stdout
    breakdown = json.loads(out.read_text())["sensor_breakdown"]
    assert [r["case"] for r in breakdown] == [
        "off", "v2v", "extended neighbours", "occlusion", "lidar", "rasters", "rasters + rgb", "all + v2v",
    ]  # fmt: skip
    for r in breakdown:
        assert r["batch"] == 2 and r["agent_steps_per_s"] > 0 and r["us_per_agent_step"] > 0
        assert r["extra_us_per_agent_step"] == r["us_per_agent_step"] - breakdown[0]["us_per_agent_step"]
    assert "Each sensor alone" in done.stdout


def test_each_row_of_the_sensor_breakdown_turns_on_what_it_names():
    """A row's cost is its sensor's only if the row's scenario has that sensor and no other."""
    from smarts.diagnostic.batched_step import sensor_parts
    from smarts.diagnostic.scenarios import sensor_scenario
    from smarts.env.batched import BatchedDriving

    added = {
        "off": set(), "v2v": {"messages", "message_mask"}, "extended neighbours": set(), "occlusion": set(),
        "lidar": {"lidar", "lidar_hit"}, "rasters": {"rasters"}, "rasters + rgb": {"rasters", "rgb"},
        "all + v2v": {"messages", "message_mask", "lidar", "lidar_hit", "rasters", "rgb"},
    }  # fmt: skip
    widths = {}
    for case, (interface, comms) in sensor_parts().items():
        env = BatchedDriving([sensor_scenario(2, 6, 20, interface, comms)])
        try:
            keys = set(env.observation_space.spaces)
            widths[case] = env.observation_space["neighbours"].shape[1]
        finally:
            env.close()
        base = {"ego", "events", "goal", "neighbour_mask", "neighbours", "signal", "waypoint_mask", "waypoints"}
        assert keys - base == added[case], case
    # extended features widen each neighbour's row, occlusion adds its visibility column
    assert widths["off"] < widths["occlusion"] < widths["extended neighbours"] < widths["all + v2v"]


def test_bad_flags_name_the_flag():
    done = subprocess.run([sys.executable, "-m", "smarts.diagnostic", "--batched", "--batches", "0,4"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2 and "--batches: expected comma-separated positive integers" in done.stderr
    done = subprocess.run([sys.executable, "-m", "smarts.diagnostic", "--batched", "--cases", "fast"],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2 and "--cases: unknown case(s) ['fast']" in done.stderr


def test_the_mix_case_cycles_through_the_platoon_scenarios_on_their_maps():
    from smarts.benchmark.suites import load_suite
    from smarts.diagnostic.batched_step import case_specs

    suite = [s.spec for s in load_suite("adaptive").scenarios]
    specs = case_specs("mix_lane", len(suite) + 2)
    assert [s.name for s in specs] == [s.name for s in suite] + [suite[0].name, suite[1].name]
    assert len({map_path(s) for s in specs}) > 1
    assert {a.controller for s in specs for a in s.agents} == {"lane_relative"}


def test_ppo_settings_are_trained_and_reported(tmp_path):
    """Two PPO settings (epochs 2 and 1, the second with its own learning rate) trained for real,
    without backend or sensor rows."""
    out = tmp_path / "ppo.json"
    done = subprocess.run(
        [sys.executable, "-m", "smarts.diagnostic", "--batched", "--batches", "none", "--sensor-batch", "0",
         "--ppo-steps", "64", "--ppo-envs", "2", "--ppo-frames", "32", "--ppo-minibatch", "16", "--ppo-epochs", "2,1",
         "--ppo-workers", "0", "--ppo-lr", "0.0001,0.0003", "--ppo-dir", str(tmp_path / "runs"), "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert report["rows"] == [] and report["sensors"] == []
    rows = report["ppo"]
    assert [(r["epochs"], r["lr"], r["workers"], r["envs"]) for r in rows] == [(2, 0.0001, 0, 2), (1, 0.0003, 0, 2)]
    assert all(r["env_steps_per_s"] > 0 and r["runs_env_steps_per_s"] == [r["env_steps_per_s"]] for r in rows)
    assert all(r["update_s"] > 0 and r["wait_s"] >= 0 for r in rows)  # medians over the batches
    assert rows[1]["ratio_to_first"] == rows[1]["env_steps_per_s"] / rows[0]["env_steps_per_s"]
    (stamp,) = (tmp_path / "runs").iterdir()  # each run in its own folder, with the asked settings
    configs = {f.name: json.loads((f / "config.json").read_text()) for f in stamp.iterdir()}
    assert {k: (c["epochs"], c["lr"]) for k, c in configs.items()} == {
        "setting0_round0": (2, 0.0001), "setting1_round0": (1, 0.0003)
    }  # fmt: skip
    assert "PPO platoon end to end" in done.stdout


def test_ppo_rounds_alternate_the_settings_and_take_medians(tmp_path, monkeypatch):
    """The order of the runs (A B A B A B) and the medians, with the training run replaced by a
    record of the calls (the test above trains for real)."""
    from smarts.diagnostic import batched_step

    calls = []

    def rate(setting, steps, out, extra=()):
        calls.append((setting.epochs, Path(out).name))
        return {**setting._asdict(), "total_steps": steps, "options": list(extra), "update_s": 0.5, "wait_s": 0.0,
                "env_steps_per_s": 1000.0 * setting.epochs + len(calls), "episode_return": 1.0}  # fmt: skip

    monkeypatch.setattr(batched_step, "ppo_rate", rate)
    settings = [batched_step.PPOSetting(256, 16384, 4096, 4, 1), batched_step.PPOSetting(512, 32768, 2048, 1, 1, 3e-4)]
    rows = batched_step.ppo_rows(settings, 100, 3, tmp_path)
    assert calls == [(4, "setting0_round0"), (1, "setting1_round0"), (4, "setting0_round1"), (1, "setting1_round1"),
                     (4, "setting0_round2"), (1, "setting1_round2")]  # fmt: skip
    assert [r["runs_env_steps_per_s"] for r in rows] == [[4001.0, 4003.0, 4005.0], [1002.0, 1004.0, 1006.0]]
    assert [r["env_steps_per_s"] for r in rows] == [4003.0, 1004.0]
    assert rows[1]["ratio_to_first"] == 1004.0 / 4003.0 and rows[1]["lr"] == 3e-4


def test_uneven_ppo_lists_name_the_flags():
    done = subprocess.run([sys.executable, "-m", "smarts.diagnostic", "--batched", "--ppo-epochs", "4,2,1",
                           "--ppo-envs", "256,512"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2
    assert "--ppo-envs, --ppo-workers: give one value or 3 (one per PPO setting)" in done.stderr
