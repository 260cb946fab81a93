"""One run contract for both training libraries (``train.run``): the same files, TensorBoard tags,
printed summary, resume and refusals for ``--lib torchrl`` and ``--lib sb3``; tiny budgets."""

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from train.__main__ import main
from train.run import SCALAR_TAGS, SUMMARY_KEYS, Run

TINY_SUITE = Path(__file__).parent / "benchmark" / "tiny_suite.yaml"
SMALL = ["--frames-per-batch", "64", "--minibatch-size", "32", "--epochs", "1", "--envs", "2", "--quiet"]


def printed_summary(text: str) -> dict:
    return json.loads(re.search(r"^\{$.*?^\}$", text, re.S | re.M).group(0))


def run_files(out: Path) -> set[str]:
    """The run folder's files, event file names and SB3's own zips left out."""
    names = set()
    for path in out.rglob("*"):
        if path.is_file() and not path.name.endswith("_sb3.zip"):
            rel = path.relative_to(out).as_posix()
            rel = re.sub(r"events\.out\.tfevents\..*", "events", rel)
            # An evaluation names the policy after its library or run folder (torchrl_step_N_policy).
            names.add(re.sub(r"(torchrl|sb3)(?=[^/]*_policy/)", "LIB", rel))
    return names


def scalar_tags(out: Path) -> set[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0})
    acc.Reload()
    return set(acc.Tags()["scalars"])


def interrupt_after_the_first_batch(monkeypatch) -> Callable[[], None]:
    """Make training raise KeyboardInterrupt (a Ctrl-C) right after its first batch is saved and
    logged; returns the function that makes it run on normally again."""
    end_of_batch = Run.end_of_batch

    def stop(self, step, *args):
        end_of_batch(self, step, *args)
        raise KeyboardInterrupt

    monkeypatch.setattr(Run, "end_of_batch", stop)
    return lambda: monkeypatch.setattr(Run, "end_of_batch", end_of_batch)


def test_both_libraries_write_the_same_run(tmp_path, capsys):
    from stable_baselines3 import PPO

    from agents.loader import load_policy_file

    # Episodes of 40 steps (so both end some in every batch); evaluations in this process (no start-up).
    base = ["ppo", "--task", "drive", "--scenarios", f"{TINY_SUITE}:t1_left", "--total-steps", "256",
            "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1", "--envs", "2", "--eval-every", "128",
            "--eval-episodes", "1", "--eval-suite", str(TINY_SUITE), "--eval-workers", "1", "--quiet"]  # fmt: skip
    files, tags, summaries = {}, {}, {}
    for lib in ("torchrl", "sb3"):
        out = tmp_path / lib
        assert main([*base, "--lib", lib, "--out-dir", str(out)]) == 0
        summaries[lib] = printed_summary(capsys.readouterr().out)
        files[lib], tags[lib] = run_files(out), scalar_tags(out)
        for name in ("last", "best", "final"):
            blob = torch.load(out / f"{name}.pt", weights_only=True)
            assert blob["config"]["lib"] == lib and "optimizer" in blob and "loss/objective" in blob["metrics"]
        assert "eval/S_bench" in torch.load(out / "best.pt", weights_only=True)["metrics"]  # its held-out score
    assert files["torchrl"] == files["sb3"]
    for name in ("config.json", "last.pt", "best.pt", "final.pt", "tensorboard/events", "evals/step_128/report.md",
                 "evals/step_128/policy.pt", "eval/report.md", "eval/results.json"):  # fmt: skip
        assert name in files["sb3"], name
    for lib in ("torchrl", "sb3"):
        assert set(SCALAR_TAGS) | {"eval/S_bench", "eval/PR"} <= tags[lib], lib
        assert list(summaries[lib])[: len(SUMMARY_KEYS)] == list(SUMMARY_KEYS)
        assert summaries[lib]["steps"] == 256 and summaries[lib]["eval/S_bench"] is not None
    assert set(summaries["torchrl"]) == set(summaries["sb3"])
    # SB3's own save beside every checkpoint, readable by SB3 itself, acting as the exported policy.
    out = tmp_path / "sb3"
    assert {p.name for p in out.glob("*_sb3.zip")} == {"last_sb3.zip", "best_sb3.zip", "final_sb3.zip"}
    model = PPO.load(out / "final_sb3.zip", device="cpu")
    assert model.num_timesteps == 256
    exported = load_policy_file(out / "final.pt")
    obs = {k: np.random.default_rng(0).normal(size=(3, *space.shape)).astype(np.float32)
           for k, space in model.observation_space.spaces.items()}  # fmt: skip
    action, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(exported.act(obs), np.clip(action, -1, 1), atol=1e-4)  # commands: [-1, 1]


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_resume_continues_from_the_saved_step_and_the_folder_is_otherwise_never_reused(tmp_path, capsys, lib):
    out = tmp_path / "run"
    base = ["ppo", "--task", "platoon", "--lib", lib, "--scenarios", "adaptive:a01_straight_free", *SMALL,
            "--eval-episodes", "0", "--out-dir", str(out)]  # fmt: skip
    assert main([*base, "--total-steps", "128"]) == 0
    first = torch.load(out / "final.pt", weights_only=True)
    before = (out / "final.pt").read_bytes()
    # A second run into the same folder is refused before anything is written.
    assert main([*base, "--total-steps", "128"]) == 2
    assert "already holds a training run" in capsys.readouterr().err
    assert (out / "final.pt").read_bytes() == before
    # --resume of its own checkpoint continues it: networks, optimiser and step count.
    assert main([*base, "--total-steps", "256", "--resume", str(out / "last.pt")]) == 0
    second = torch.load(out / "final.pt", weights_only=True)
    assert (first["step"], second["step"]) == (128, 256)
    assert float(second["optimizer"]["state"][0]["step"]) > float(first["optimizer"]["state"][0]["step"])
    weights = "actor" if lib == "torchrl" else "policy"
    name = next(iter(first[weights]))
    assert not torch.equal(first[weights][name], second[weights][name])
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0})
    acc.Reload()
    assert [e.step for e in acc.Scalars("loss/objective")] == [64, 128, 192, 256]
    if lib == "sb3":
        from stable_baselines3 import PPO

        assert PPO.load(out / "final_sb3.zip", device="cpu").num_timesteps == 256
    # Already at the budget: refused, nothing built.
    assert main([*base, "--total-steps", "256", "--resume", str(out / "final.pt")]) == 2
    assert "already at 256 steps" in capsys.readouterr().err


@pytest.mark.parametrize(
    "trained, resumed, flags, what",
    [
        ("sb3", "torchrl", [], "library 'sb3'"),
        ("torchrl", "sb3", [], "library 'torchrl'"),
        ("sb3", "sb3", ["--hidden", "32,32"], "hidden layers"),
        ("sb3", "sb3", ["--controller", "direct"], "controller"),
    ],
)
def test_resume_refuses_another_library_or_setup_before_touching_the_run(
    tmp_path, capsys, trained, resumed, flags, what
):
    base = ["ppo", "--task", "platoon", "--scenarios", "adaptive:a01_straight_free", *SMALL, "--eval-episodes", "0"]
    assert main([*base, "--lib", trained, "--total-steps", "64", "--out-dir", str(tmp_path / "first")]) == 0
    second = tmp_path / "second"
    args = [*base, "--lib", resumed, "--total-steps", "128", "--out-dir", str(second),
            "--resume", str(tmp_path / "first" / "final.pt"), *flags]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"trained with {what}" in err and "final.pt" in err
    assert not second.exists()


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_ctrl_c_saves_interrupted_checkpoint(tmp_path, monkeypatch, lib):
    run_on = interrupt_after_the_first_batch(monkeypatch)
    out = tmp_path / "run"
    code = main(["ppo", "--task", "platoon", "--lib", lib, "--scenarios", "adaptive:a01_straight_free", *SMALL,
                 "--total-steps", "256", "--eval-episodes", "0", "--out-dir", str(out)])  # fmt: skip
    assert code == 130  # the shell's code for Ctrl-C, after one line, no traceback
    blob = torch.load(out / "interrupted.pt", weights_only=True)
    assert blob["step"] == 64 and "optimizer" in blob
    assert not (out / "final.pt").exists()
    assert (out / "interrupted_sb3.zip").is_file() == (lib == "sb3")
    # The interrupted run continues from interrupted.pt to its budget.
    run_on()
    assert main(["ppo", "--task", "platoon", "--lib", lib, "--scenarios", "adaptive:a01_straight_free", *SMALL,
                 "--total-steps", "256", "--eval-episodes", "0", "--out-dir", str(out), "--quiet",
                 "--resume", str(out / "interrupted.pt")]) == 0  # fmt: skip
    assert torch.load(out / "final.pt", weights_only=True)["step"] == 256


def test_evaluations_in_the_training_process_do_not_change_an_sb3_run(tmp_path):
    base = ["ppo", "--lib", "sb3", "--task", "drive", "--scenarios", f"{TINY_SUITE}:t1_left", "--total-steps", "384",
            "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1", "--envs", "1",
            "--eval-suite", str(TINY_SUITE), "--quiet"]  # fmt: skip
    assert main([*base, "--eval-every", "128", "--eval-episodes", "1", "--eval-workers", "1",
                 "--out-dir", str(tmp_path / "a")]) == 0  # fmt: skip
    assert main([*base, "--eval-episodes", "0", "--out-dir", str(tmp_path / "b")]) == 0
    with_eval = torch.load(tmp_path / "a" / "final.pt", weights_only=True)
    without = torch.load(tmp_path / "b" / "final.pt", weights_only=True)
    assert with_eval["step"] == without["step"] == 384
    assert (tmp_path / "a" / "evals" / "step_256" / "report.md").is_file()
    for name, tensor in without["policy"].items():
        assert torch.equal(with_eval["policy"][name], tensor), name


def test_best_pt_holds_the_highest_held_out_score_so_far(tmp_path, monkeypatch):
    """Stopped right after the first periodic evaluation: that evaluation is the best so far, so
    best.pt holds that step's weights and its held-out S_bench (as logged to TensorBoard)."""
    run_on = interrupt_after_the_first_batch(monkeypatch)
    out = tmp_path / "run"
    code = main(["ppo", "--task", "drive", "--scenarios", f"{TINY_SUITE}:t1_left", *SMALL, "--total-steps", "256",
                 "--eval-every", "64", "--eval-episodes", "1", "--eval-workers", "1", "--eval-suite", str(TINY_SUITE),
                 "--out-dir", str(out)])  # fmt: skip
    assert code == 130
    best = torch.load(out / "best.pt", weights_only=True)
    last = torch.load(out / "last.pt", weights_only=True)
    assert best["step"] == last["step"] == 64
    for name, tensor in last["actor"].items():
        assert torch.equal(best["actor"][name], tensor), name
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0})
    acc.Reload()
    logged = [(e.step, e.value) for e in acc.Scalars("eval/best_S_bench")]
    assert logged == [(64, pytest.approx(best["metrics"]["eval/S_bench"]))]
    # Resumed, later evaluations replace best.pt only when they score higher: with the recorded
    # score raised to the maximum (1.0), neither the periodic nor the final evaluation may.
    best["metrics"]["eval/S_bench"] = 1.0
    torch.save(best, out / "best.pt")
    run_on()
    assert main(["ppo", "--task", "drive", "--scenarios", f"{TINY_SUITE}:t1_left", *SMALL, "--total-steps", "192",
                 "--eval-every", "64", "--eval-episodes", "1", "--eval-workers", "1", "--eval-suite", str(TINY_SUITE),
                 "--out-dir", str(out), "--resume", str(out / "last.pt")]) == 0  # fmt: skip
    assert (out / "evals" / "step_128" / "results.json").is_file() and (out / "eval" / "results.json").is_file()
    assert torch.load(out / "best.pt", weights_only=True)["step"] == 64


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_tensorboard_holds_the_update_diagnostics_and_the_config(tmp_path, lib):
    """Read back from the event files: clip fraction, explained variance and gradient norm after
    every batch, a KL estimate that is never negative, and the run's settings as text."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / lib
    args = ["ppo", "--task", "platoon", "--lib", lib, "--scenarios", "adaptive:a01_straight_free", "--total-steps",
            "192", "--eval-episodes", "0", "--out-dir", str(out), *SMALL]  # fmt: skip
    assert main(args) == 0
    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0, "tensors": 0})
    acc.Reload()

    def values(tag: str) -> np.ndarray:
        return np.array([e.value for e in acc.Scalars(tag)])

    batches = 3  # 192 steps of 2 slots in batches of 64
    clip, explained, grad, kl = (values(t) for t in ("policy/clip_fraction", "train/explained_variance",
                                                      "train/grad_norm", "policy/kl_approx"))  # fmt: skip
    assert len(clip) == len(explained) == len(grad) == len(kl) == batches
    assert ((clip >= 0) & (clip <= 1)).all() and np.isfinite(explained).all()
    assert (grad > 0).all() and (kl >= 0).all()
    text = acc.Tensors("config/text_summary")[0].tensor_proto.string_val[0].decode()
    config = json.loads(text.strip().strip("`").strip())
    assert config == json.loads((out / "config.json").read_text()) and config["lib"] == lib


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_a_log_that_is_not_a_terminal_gets_the_run_folder_first_then_one_line_per_batch(tmp_path, lib):
    """stdout to a pipe (a cluster job's log): the run folder and the TensorBoard command before
    anything else, then one plain progress line per batch (no bar's control characters)."""
    import subprocess
    import sys

    out = tmp_path / lib
    command = [sys.executable, "-m", "train", "ppo", "--task", "platoon", "--lib", lib, "--scenarios",
               "adaptive:a01_straight_free", "--total-steps", "192", "--frames-per-batch", "64", "--minibatch-size",
               "32", "--epochs", "1", "--envs", "2", "--eval-episodes", "0", "--out-dir", str(out)]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[0] == f"run folder: {out}"
    assert lines[1] == f"TensorBoard: tensorboard --logdir {out / 'tensorboard'}"
    progress = [line for line in lines if line.startswith("PPO")]
    assert len(progress) == 3 and "\x1b" not in done.stdout
    assert progress[0].startswith("PPO") and "64/192 steps (33%)" in progress[0] and "env-steps/s" in progress[0]
    assert "192/192 steps (100%)" in progress[-1]
