"""Outputs under an unlucky disk: a run folder or benchmark ``--out`` that refuses writes, cannot
be made or lacks free space fails before the run starts, naming the folder; a disk that fills
up while training is a clear error that leaves the previous checkpoint intact and no temporary
file behind.

The full disk is simulated at the operating system's write (``os.write`` as the checkpoint writer
calls it raises ``ENOSPC``); read-only folders use permission bits, skipped where they do not bind
(root); a path under a regular file cannot be made by anyone."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
import torch

import agents.checkpoint
from agents.checkpoint import CheckpointWriteError, read_checkpoint
from tests.builders import PERMISSIONS_SKIP
from train.__main__ import main

ROOT = Path(__file__).resolve().parents[1]
TINY_SUITE = ROOT / "tests" / "benchmark" / "tiny_suite.yaml"
TRAIN = ["ppo", "--task", "drive", "--scenarios", f"{TINY_SUITE}:t1_left", "--total-steps", "192",
         "--frames-per-batch", "64", "--minibatch-size", "32", "--epochs", "1", "--envs", "2", "--eval-episodes", "0",
         "--quiet"]  # fmt: skip
BENCH = [
    "benchmark",
    "--suite",
    str(TINY_SUITE),
    "--agent",
    "zoo:keep-lane",
    "--episodes",
    "1",
    "--workers",
    "1",
    "--quiet",
]


class DiskFillsUp:
    """The ``os`` module as the checkpoint writer sees it, whose writes fail with ENOSPC (no space
    left on the device) once ``writes`` of them have succeeded."""

    def __init__(self, writes: int):
        self.left = writes

    def __getattr__(self, name: str):
        return getattr(os, name)

    def write(self, fd: int, data) -> int:
        if self.left <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.left -= 1
        return os.write(fd, data)


def leftovers(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.name.endswith(".tmp") or ".tmp" in p.suffixes)


# ------------------------------------------------------------------ a full disk
def test_a_full_disk_while_writing_a_checkpoint_keeps_the_previous_one_and_no_temporary_file(tmp_path, monkeypatch):
    from agents.planners.nets import StopMoveNet, load_net, save_net

    path = tmp_path / "tf.pt"
    save_net(path, "tf-stop-move", StopMoveNet(hidden=8, layers=1), {"step": 1})
    before = path.read_bytes()
    monkeypatch.setattr(agents.checkpoint, "os", DiskFillsUp(writes=0))
    with pytest.raises(CheckpointWriteError) as raised:
        save_net(path, "tf-stop-move", StopMoveNet(hidden=8, layers=1), {"step": 2})
    assert str(raised.value) == (f"{path}: could not write the checkpoint (no space left on the device); "
                                 "its previous version is intact")  # fmt: skip
    assert path.read_bytes() == before and leftovers(tmp_path) == []
    monkeypatch.undo()
    assert load_net(path, "tf-stop-move")[1] == {"step": 1}


def test_a_full_disk_during_training_is_a_clear_error_and_last_pt_stays_intact(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    monkeypatch.setattr(agents.checkpoint, "os", DiskFillsUp(writes=1))  # the first batch's last.pt fits
    assert main([*TRAIN, "--out-dir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"error: {out / 'last.pt'}: could not write the checkpoint (no space left on the device); " \
           "its previous version is intact" in err  # fmt: skip
    monkeypatch.undo()
    assert leftovers(out) == []
    assert read_checkpoint(out / "last.pt")["step"] == 64  # the last one written whole


# ------------------------------------------------------------------ a run folder that cannot take the run
def test_a_run_folder_that_cannot_be_made_fails_before_training(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert main([*TRAIN, "--out-dir", str(blocker / "run")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"error: run folder {blocker / 'run'}: cannot be made there: {blocker} is not a folder"
    assert sorted(tmp_path.iterdir()) == [blocker]


@pytest.mark.parametrize("command", ["tf-bc", "vcr-classifier", "aid-predictor"])
def test_the_planner_trainers_check_their_out_folder_before_generating_data(tmp_path, capsys, command):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert main([command, "--out", str(blocker / "run"), "--quiet"]) == 2
    assert capsys.readouterr().err.strip() == (f"error: run folder {blocker / 'run'}: cannot be made there: "
                                               f"{blocker} is not a folder")  # fmt: skip


@PERMISSIONS_SKIP
def test_a_read_only_run_folder_fails_before_training(tmp_path, capsys):
    read_only = tmp_path / "ro"
    read_only.mkdir()
    read_only.chmod(0o500)
    try:
        assert main([*TRAIN, "--out-dir", str(read_only / "run")]) == 2
        err = capsys.readouterr().err
        assert f"error: run folder {read_only / 'run'}: cannot write there (permission denied)" in err
        assert "Traceback" not in err and list(read_only.iterdir()) == []
    finally:
        read_only.chmod(0o700)


def test_a_run_folder_without_the_free_space_fails_before_training(tmp_path, monkeypatch, capsys):
    import train.run

    monkeypatch.setattr(train.run, "RUN_FREE_BYTES", 1 << 62)  # more than any disk holds
    assert main([*TRAIN, "--out-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert f"error: run folder {tmp_path / 'run'}: " in err and "MiB free on its disk; the run needs about" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ a benchmark --out that cannot take the report
@pytest.fixture
def no_episodes(monkeypatch):
    """Running any episode fails the test: the output folder must be refused before."""
    import smarts.benchmark.runner as runner

    def ran(*args, **kwargs):
        raise AssertionError("an episode ran before the output folder was checked")

    monkeypatch.setattr(runner, "run_jobs", ran)
    monkeypatch.setattr(runner, "run_episode", ran)


@PERMISSIONS_SKIP
def test_a_read_only_benchmark_out_fails_before_any_episode(tmp_path, capsys, no_episodes):
    read_only = tmp_path / "ro"
    read_only.mkdir()
    read_only.chmod(0o500)
    try:
        assert main([*BENCH, "--out", str(read_only)]) == 2
        err = capsys.readouterr().err
        assert f"error: output folder {read_only}: cannot write there (permission denied)" in err
        assert list(read_only.iterdir()) == []
    finally:
        read_only.chmod(0o700)


def test_a_benchmark_out_that_cannot_be_made_fails_before_any_episode(tmp_path, capsys, no_episodes):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    assert main([*BENCH, "--out", str(blocker / "bench")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: output folder {blocker / 'bench'}: cannot be made there: "
                                               f"{blocker} is not a folder")  # fmt: skip


def test_a_benchmark_out_without_the_free_space_fails_before_any_episode(tmp_path, monkeypatch, capsys, no_episodes):
    import smarts.benchmark.jobs as jobs

    monkeypatch.setattr(jobs, "EPISODE_LOG_BYTES", 1 << 58)  # 9 episodes of these fill any disk
    assert main([*BENCH, "--out", str(tmp_path / "bench")]) == 2
    err = capsys.readouterr().err
    assert f"error: output folder {tmp_path / 'bench'}: " in err and "MiB free on its disk" in err
    assert list(tmp_path.iterdir()) == []


def test_the_check_leaves_nothing_behind_in_a_folder_it_accepts(tmp_path):
    from smarts.benchmark.jobs import check_output_folder

    check_output_folder(tmp_path / "new" / "run", 1)
    check_output_folder(tmp_path, 1)
    assert list(tmp_path.iterdir()) == []


def test_a_write_error_mid_run_is_one_line_without_a_traceback(tmp_path, monkeypatch, capsys):
    """A folder that stops taking files after the checks (the report at the end of a benchmark)."""
    import smarts.benchmark.report as report

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "bench" / "results.json"))

    monkeypatch.setattr(report, "write_report", full)
    assert main([*BENCH, "--out", str(tmp_path / "bench")]) == 1
    err = capsys.readouterr().err
    assert err.strip() == f"error: {tmp_path / 'bench' / 'results.json'}: No space left on device " \
                          "(the files written before it are kept)"  # fmt: skip


def test_a_full_disk_while_writing_a_ppo_checkpoint_keeps_the_previous_one(tmp_path, monkeypatch):
    """PPO checkpoints go through the same writer (torch's own file writer reported a full disk as
    an opaque RuntimeError and left its partial ``.tmp`` file)."""
    from agents.ppo import Actor, Critic, ObservationLayout, ObsNormalizer, save_checkpoint

    layout = ObservationLayout(("ego",), ((4,),))
    saved = save_checkpoint(tmp_path / "p.pt", actor=Actor(4, 2, (8,)), critic=Critic(4, (8,)), normalizer=ObsNormalizer(4),
                            layout=layout, low=[-1.0, -1.0], high=[1.0, 1.0], action_space="relative_target_pose",
                            config={"hidden": [8]}, step=3, metrics={})  # fmt: skip
    before = saved.read_bytes()
    monkeypatch.setattr(agents.checkpoint, "os", DiskFillsUp(writes=0))
    with pytest.raises(CheckpointWriteError, match="no space left on the device"):
        save_checkpoint(saved, actor=Actor(4, 2, (8,)), critic=Critic(4, (8,)), normalizer=ObsNormalizer(4), layout=layout,
                        low=[-1.0, -1.0], high=[1.0, 1.0], action_space="relative_target_pose", config={"hidden": [8]},
                        step=4, metrics={})  # fmt: skip
    monkeypatch.undo()
    assert saved.read_bytes() == before and leftovers(tmp_path) == []
    assert torch.load(saved, weights_only=True)["step"] == 3
