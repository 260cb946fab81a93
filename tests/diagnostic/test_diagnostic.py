import json

from smarts.diagnostic.__main__ import main


def test_diagnostic_writes_a_table_and_json(tmp_path, capsys):
    out = tmp_path / "diag.json"
    args = [
        "--agents",
        "1,3",
        "--vehicles",
        "10",
        "--traffic",
        "sumo,builtin",
        "--steps",
        "5",
        "--warmup",
        "1",
        "--cpu",
        "1,sumo10",
        "--stages",
    ]
    assert main([*args, "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    cases = report["cases"]
    assert [c["agents"] for c in cases] == [1, 3]
    for c in cases:
        assert c["env_ms_mean"] > 0 and c["sim_ms_mean"] > 0 and c["obs_ms_mean"] > 0
        assert c["agent_steps_per_s"] == c["agents"] * c["env_steps_per_s"]
    traffic = report["traffic_cases"]
    assert [(c["engine"], c["vehicles"]) for c in traffic] == [("sumo", 10), ("builtin", 10)]
    for c in traffic:
        assert c["vehicles_on_road"] >= 10 and c["step_ms"] > c["provider_ms"] > 0
    cpu = report["cpu_cases"]
    assert [c["case"].split(",")[0] for c in cpu] == ["1 agent", "10 SUMO vehicles (10 on the road)"]
    for c in cpu:
        assert c["cpu_us_median"] > 0 and c["steps"] >= 5  # timed steps in all
        assert "map, route, events" in c["stages_us"] and "other" in c["stages_us"]
    printed = capsys.readouterr().out
    assert "agent-steps/s" in printed and "traffic provider" in printed and "CPU by stage" in printed


def test_cpu_rows_against_a_baseline_tree_alternate_fresh_interpreters():
    from pathlib import Path

    from smarts.diagnostic import cpu_step

    root = str(Path(cpu_step.__file__).resolve().parents[2])  # this tree as its own baseline
    (row,) = cpu_step.compare(root, ["1"], steps=3, warmup=1, rounds=1)
    assert row["case"] == "1" and row["baseline_us"] > 0 and row["this_us"] > 0
    assert row["ratio"] == row["this_us"] / row["baseline_us"] and len(row["rounds"]["this"]) == 1
