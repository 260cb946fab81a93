"""The replay cases of ``python -m smarts.diagnostic`` (tiny budgets; the timings are its job)."""

from __future__ import annotations

import json

import pytest

from smarts.diagnostic.__main__ import main
from smarts.diagnostic.replay_step import replay_step_benchmark


def test_diagnostic_writes_replay_cases(tmp_path, capsys):
    out = tmp_path / "diag.json"
    args = ["--agents", "1", "--traffic", "none", "--sensors", "none", "--replay", "3,12+", "--steps", "5", "--warmup", "1"]
    assert main([*args, "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["replay_cases"]
    assert [(r["n_vehicles"], r["take_over"]) for r in rows] == [(3, False), (12, True)]
    assert rows[0]["replayed_min"] == 3 and rows[1]["replayed_min"] == 11  # one is the agent's
    for r in rows:
        assert r["agent_on_road"] and r["sim_step_ms_median"] > r["provider_ms_median"] > 0
    assert "NGSIM replay" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--replay", "x", "--out", str(out)])


def test_every_replayed_vehicle_stays_for_the_timed_steps():
    r = replay_step_benchmark(50, steps=30, warmup=2, take_over=True)
    assert r["replayed_min"] == 49 and r["replayed_mean"] == 49.0 and r["agent_on_road"]
