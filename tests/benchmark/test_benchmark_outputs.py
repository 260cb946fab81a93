"""Where benchmark runs go: each run in its own numbered folder (never over another run), files
readable by group and others, ``--resume`` finishing the latest run, and a training run folder
accepted as an agent (its best.pt), named by its run in the report."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

import zoo.registry
from train.__main__ import main

TINY = str(Path(__file__).with_name("tiny_suite.yaml"))


@pytest.fixture
def in_empty_folder(tmp_path, monkeypatch):
    """The working folder of a new user: empty, umask 022."""
    monkeypatch.chdir(tmp_path)
    before = os.umask(0o022)
    yield tmp_path
    os.umask(before)


def bench(*extra: str) -> int:
    return main(["benchmark", "--suite", TINY, "--episodes", "1", "--workers", "1", "--quiet", *extra])


def test_two_benchmarks_into_the_default_folder_are_both_kept(in_empty_folder, capsys):
    assert bench("--agent", "zoo:keep-lane") == 0
    assert bench("--agent", "zoo:random") == 0
    root = in_empty_folder / "runs" / "benchmark" / "tiny"
    first, second = root / "001", root / "002"
    assert (root / "latest").resolve() == second.resolve()
    assert "report: runs/benchmark/tiny/002/report.md" in capsys.readouterr().err
    one = json.loads((first / "results.json").read_text())
    two = json.loads((second / "results.json").read_text())
    assert one["references"] == ["zoo:random", "zoo:stand-still"] and "zoo:keep-lane" in one["agents"]
    assert two["references"] == ["zoo:keep-lane", "zoo:stand-still"] and "zoo:random" in two["agents"]
    # Each run's logs are its own: the first run's viewer folder still holds only its 3 x 2 episodes.
    assert len(list((first / "logs").rglob("*.npz"))) == len(list((second / "logs").rglob("*.npz"))) == 6
    # Readable by group and others (the atomic writes used to leave 0600).
    for path in [first / "report.md", first / "results.json", first / "results.csv",
                 *(first / "logs").rglob("*.npz"), *(first / "plots").glob("*.png")]:  # fmt: skip
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path


def test_an_out_folder_holding_a_run_is_refused_and_resume_finishes_the_latest(in_empty_folder, capsys):
    assert bench("--agent", "zoo:keep-lane", "--out", "mine") == 0
    before = (in_empty_folder / "mine" / "report.md").stat().st_mtime_ns
    assert bench("--agent", "zoo:random", "--out", "mine") == 2
    err = capsys.readouterr().err
    assert "error: output folder mine: already holds a benchmark run" in err and "--resume" in err
    assert (in_empty_folder / "mine" / "report.md").stat().st_mtime_ns == before
    # --resume without --out: the suite's latest numbered run; with none yet, a clear error.
    assert bench("--agent", "zoo:keep-lane", "--resume") == 2
    assert "--resume: no benchmark run of suite 'tiny'" in capsys.readouterr().err
    assert bench("--agent", "zoo:keep-lane") == 0
    log = next((in_empty_folder / "runs/benchmark/tiny/001/logs").rglob("*.npz"))
    log.unlink()
    assert bench("--agent", "zoo:keep-lane", "--resume") == 0
    assert log.is_file() and not (in_empty_folder / "runs/benchmark/tiny/002").exists()


@pytest.mark.parametrize("name", ["zoo", "./agents"])
def test_an_out_folder_that_would_hide_a_package_is_refused_before_anything_is_written(in_empty_folder, capsys, name):
    """``--out zoo`` in the current directory would be imported in place of the zoo package by the
    workers that load the agents: refused up front, naming the folder, and nothing is created."""
    assert bench("--agent", "zoo:keep-lane", "--out", name) == 2
    err = capsys.readouterr().err
    package = name.split("/")[-1]
    assert f"hides the installed package {package!r}" in err and f"runs/{package}" in err
    assert not (in_empty_folder / package).exists()
    assert bench("--agent", "zoo:keep-lane", "--out", f"runs/{package}") == 0  # one level down is fine


def test_eval_requires_an_agent(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["eval", "--suite", TINY])
    assert stop.value.code == 2 and "the following arguments are required: --agent" in capsys.readouterr().err


def test_a_training_run_folder_is_an_agent_named_by_its_run(in_empty_folder, capsys):
    run = in_empty_folder / "runs" / "train" / "platoon" / "003"
    run.mkdir(parents=True)
    checkpoint = (Path(zoo.registry.ZOO_DIR) / "checkpoints" / "platoon-c.pt").read_bytes()
    (run / "last.pt").write_bytes(checkpoint)
    (run.parent / "latest").symlink_to("003")
    # Without best.pt: refused, naming the folder and what it holds.
    assert main(["eval", "--agent", "runs/train/platoon/latest", "--suite", TINY, "--episodes", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "agent 'runs/train/platoon/latest': a folder without best.pt" in err and "it holds last.pt" in err
    (run / "best.pt").write_bytes(checkpoint)
    assert main(["eval", "--agent", "runs/train/platoon/latest", "--suite", TINY, "--episodes", "1", "--workers", "1",
                 "--quiet", "--out", "ev"]) == 0  # fmt: skip
    doc = json.loads((in_empty_folder / "ev" / "results.json").read_text())
    assert "runs/train/platoon/latest/best.pt" in doc["agents"]
    assert doc["agents"]["runs/train/platoon/latest/best.pt"]["action_space"] == "continuous"
    assert "| platoon/003/best |" in (in_empty_folder / "ev" / "report.md").read_text()
    assert (in_empty_folder / "ev" / "logs" / "platoon_003_best").is_dir()
