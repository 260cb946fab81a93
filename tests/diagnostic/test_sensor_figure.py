"""The README figure command and the diagnostic's all-sensors case."""

import json

import pytest
from PIL import Image

from smarts.diagnostic.__main__ import main as diagnostic_main
from smarts.diagnostic.sensor_figure import main as figure_main
from smarts.diagnostic.sensor_figure import make_figure


def test_figure_command_writes_a_small_png(tmp_path, capsys):
    out = tmp_path / "figure1.png"
    assert figure_main(["--out", str(out), "--steps", "5"]) == 0
    assert out.stat().st_size < 200_000
    image = Image.open(out)
    assert image.mode == "RGB" and image.size[0] >= 512
    pixels = image.convert("RGB").getcolors(1 << 16)
    assert len(pixels) > 8  # a picture, not a blank canvas
    assert "wrote" in capsys.readouterr().out


def test_figure_policy_comes_from_the_resolver_and_must_fit_the_agent(capsys):
    asked = []

    class Throttle:
        action_space = "continuous"

    def resolver(locator):
        asked.append(locator)
        return Throttle()

    with pytest.raises(ValueError, match="policy 'mine:throttle': it acts in 'continuous'"):
        make_figure(steps=1, policy="mine:throttle", policy_resolver=resolver)
    assert asked == ["mine:throttle"]
    with pytest.raises(SystemExit):
        figure_main(["--policy", "zoo:no-such-agent", "--steps", "1"])
    assert "--policy 'zoo:no-such-agent'" in capsys.readouterr().err


def test_diagnostic_times_the_all_sensors_case(tmp_path, capsys):
    out = tmp_path / "diag.json"
    args = ["--agents", "1", "--traffic", "none", "--sensors", "4:12", "--steps", "4", "--warmup", "1"]
    assert diagnostic_main([*args, "--out", str(out)]) == 0
    (case,) = json.loads(out.read_text())["sensor_cases"]
    assert (case["agents"], case["vehicles"]) == (4, 12)
    assert case["live_rows"] == 16
    for key in ("env_ms_mean", "obs_ms_mean", "shadows_ms_mean", "rasters_ms_mean", "lidar_ms_mean"):
        assert case[key] > 0
    assert "All sensors" in capsys.readouterr().out
