"""`python -m smarts.diagnostic --batched` on a tiny budget: rows, JSON, bad flags."""

import json
import subprocess
import sys

from smarts.scenario import map_path


def test_batched_rows_are_written_as_json(tmp_path):
    out = tmp_path / "batched.json"
    done = subprocess.run(
        [sys.executable, "-m", "smarts.diagnostic", "--batched", "--batches", "1,4", "--cases", "free_direct,lead_lane,mix_lane",
         "--steps", "10", "--warmup", "2", "--per-env-agent-steps", "20", "--sensor-batch", "2", "--out", str(out)],
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
