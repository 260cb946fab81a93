"""A wheel (``pip install .``) holds everything the checkout runs with, and runs outside it.

The wheel is built from a copy of the sources (nothing is written into the checkout) and unpacked
into a folder that a fresh interpreter imports from, in a working directory of its own: the task
configs, benchmark suites, metric constants, scenario library and zoo checkpoints must all be read
from the installed copy. ``.ci/run`` goes further and trains and benchmarks from a wheel installed
into a fresh virtual environment.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

from smarts.core.resources import config_path, configs_dir

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("smarts", "agents", "zoo", "train")
"""Top-level folders installed under their own name; ``configs/`` is installed as smarts/configs/."""


def _source_files() -> dict[str, Path]:
    """Wheel path -> source file, for every file the wheel must hold."""
    files: dict[str, Path] = {}
    for top, target in [(p, p) for p in PACKAGES] + [("configs", "smarts/configs")]:
        for path in sorted((ROOT / top).rglob("*")):
            rel = path.relative_to(ROOT / top)
            if path.is_dir() or "__pycache__" in rel.parts or any(p.startswith(".") for p in rel.parts):
                continue
            if path.suffix in (".pyc", ".nbi", ".nbc") or ".tmp." in path.name:
                continue
            files[f"{target}/{rel.as_posix()}"] = path
    return files


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for top in PACKAGES + ("configs",):
        shutil.copytree(ROOT / top, src / top, ignore=shutil.ignore_patterns("__pycache__", ".*"))
    out = tmp_path_factory.mktemp("dist")
    cmd = [sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "-q", "-w", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"building the wheel failed (needs setuptools, the test extra):\n{done.stderr}"
    (built,) = out.glob("smarts-*.whl")
    return built


def test_configs_are_found_through_the_package():
    assert config_path("train", "platoon.yaml").is_file()
    assert config_path("benchmark", "adaptive.yaml").is_file()
    # In the checkout (editable install or none) the YAML read is the one edited in configs/.
    assert configs_dir().resolve() == (ROOT / "configs").resolve()


def test_wheel_holds_every_source_and_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = _source_files()
    missing = sorted(set(expected) - names)
    assert not missing, (
        "files missing from the wheel (add their package to [tool.setuptools] packages or their "
        f"suffix to package-data in pyproject.toml): {missing}"
    )
    for required in ("smarts/configs/train/platoon.yaml", "smarts/configs/benchmark/metrics.yaml",
                     "zoo/checkpoints/platoon-rtp.pt", "zoo/cards/platoon-rtp.md"):  # fmt: skip
        assert required in names
    assert not [n for n in names if n.startswith(("tests/", "configs/"))], "only packages go into the wheel"


def test_installed_copy_reads_its_own_configs_outside_the_checkout(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    work = tmp_path / "work"
    work.mkdir()
    script = textwrap.dedent(
        f"""
        from pathlib import Path
        import smarts, zoo, train
        site = Path({str(site)!r})
        for module in (smarts, zoo, train):
            assert Path(module.__file__).is_relative_to(site), module.__file__
        from smarts.core.resources import configs_dir
        assert configs_dir().is_relative_to(site), configs_dir()
        from train.config import TASKS, load_config
        for task in TASKS:
            assert load_config(task).task == task
        from smarts.benchmark.suites import load_suite, suite_names
        assert suite_names() == ["adaptive", "collaborative"], suite_names()
        for name in suite_names():
            assert load_suite(name).scenarios
        from smarts.benchmark.metrics.params import DEFAULT_CONFIG_PATH, load_params
        assert DEFAULT_CONFIG_PATH.is_relative_to(site) and DEFAULT_CONFIG_PATH.is_file()
        load_params()
        from smarts.scenario.library import list_scenarios, load_scenario
        for name in list_scenarios():
            load_scenario(name)
        assert list_scenarios()
        from zoo.registry import CHECKPOINT, ZOO, ZOO_DIR, make_policy
        for name, (module, target, _) in ZOO.items():
            make_policy("zoo:" + name)
            if module == CHECKPOINT:
                card = ZOO_DIR / "cards" / (name + ".md")
                assert card.is_file(), card
        print("ok")
        """
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=work, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-4000:]
