"""The replay cases of ``python -m smarts.diagnostic`` (tiny budgets; the timings are its job)."""

from __future__ import annotations

import json

import pytest

from smarts.diagnostic.__main__ import main
from smarts.diagnostic.replay_step import replay_step_benchmark


def test_diagnostic_writes_replay_cases(tmp_path, capsys):
    out = tmp_path / "diag.json"
    args = [
        "--agents",
        "1",
        "--traffic",
        "none",
        "--sensors",
        "none",
        "--replay",
        "0,3,12+",
        "--steps",
        "5",
        "--warmup",
        "1",
    ]
    assert main([*args, "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["replay_cases"]
    assert [(r["n_vehicles"], r["take_over"]) for r in rows] == [(0, False), (3, False), (12, True)]
    assert [r["replayed_min"] for r in rows] == [0, 3, 11]  # one is the agent's
    assert rows[0]["provider_ms_median"] == 0.0
    for r in rows:
        lo, hi = r["env_step_ms_median_ci95"]
        assert r["agent_on_road"] and lo <= r["env_step_ms_median"] <= hi
        assert r["env_step_ms_median"] > r["sim_step_ms_median"] >= r["provider_ms_median"] >= 0
    assert "NGSIM replay" in capsys.readouterr().out
    for bad in ("x", "0+", "-1"):
        with pytest.raises(SystemExit):
            main(["--replay", bad, "--out", str(out)])


def test_every_replayed_vehicle_stays_for_the_timed_steps():
    r = replay_step_benchmark(50, steps=30, warmup=2, take_over=True)
    assert r["replayed_min"] == 49 and r["replayed_mean"] == 49.0 and r["agent_on_road"]
