"""The README's sensor example (a whole scenario file) gives the documented outputs."""

import re
from pathlib import Path

import numpy as np
import yaml

from smarts.env import DrivingParallelEnv
from smarts.scenario import read_scenario

README = (Path(__file__).resolve().parents[2] / "README.md").read_text()


def test_readme_interface_example_runs():
    block = next(b for b in re.findall(r"```yaml\n(.*?)```", README, flags=re.S) if "interface:" in b)
    data = {"name": "readme_sensors", **yaml.safe_load(block)}
    env = DrivingParallelEnv(read_scenario(data, source="README sensors"))
    obs, _ = env.reset(seed=0)
    o = obs["agent_0"]
    assert env.observation_space("agent_0").contains(o)
    assert o["rasters"].shape == (5, 64, 64) and o["rgb"].shape == (64, 64, 3)
    assert o["lidar"].shape == (64,) and o["neighbours"].shape == (8, 21) and o["ego"].shape == (13,)
    assert set(np.unique(o["lidar_hit"])) <= {0.0, 1.0, 2.0, 3.0}
    assert Path(__file__).resolve().parents[2].joinpath("docs", "figure1.png").stat().st_size < 200_000
    env.close()
