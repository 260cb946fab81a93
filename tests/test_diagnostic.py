import json

from smarts.diagnostic.__main__ import main


def test_diagnostic_writes_a_table_and_json(tmp_path, capsys):
    out = tmp_path / "diag.json"
    assert main(["--agents", "1,3", "--steps", "5", "--warmup", "1", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    cases = report["cases"]
    assert [c["agents"] for c in cases] == [1, 3]
    for c in cases:
        assert c["env_ms_mean"] > 0 and c["sim_ms_mean"] > 0 and c["obs_ms_mean"] > 0
        assert c["agent_steps_per_s"] == c["agents"] * c["env_steps_per_s"]
    assert "agent-steps/s" in capsys.readouterr().out
