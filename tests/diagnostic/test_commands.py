"""The diagnostic and docs commands the README names exist, and the reset-memory check runs."""

import importlib.util
import re
from pathlib import Path

from smarts.diagnostic.reset_memory import main as reset_memory_main

README = (Path(__file__).resolve().parents[2] / "README.md").read_text()


def test_readme_module_commands_exist():
    modules = set(re.findall(r"python -m (smarts(?:\.\w+)+)", README))
    assert {"smarts.diagnostic.reset_memory", "smarts.diagnostic.sensor_figure"} <= modules
    missing = [m for m in sorted(modules) if importlib.util.find_spec(m) is None]
    assert not missing, f"README names modules that do not exist: {missing}"


def test_reset_memory_prints_its_readings(capsys):
    reset_memory_main(["--resets", "2", "--steps", "1"])
    printed = capsys.readouterr().out
    assert "RSS after 10 warm-up resets" in printed and "kB per reset" in printed
