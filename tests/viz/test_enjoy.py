"""python -m train enjoy: a zoo policy drives a suite scenario into an MP4 (imageio-ffmpeg's own
ffmpeg) of follow-camera frames with a HUD and a legend, a TensorBoard animated image and a viewer
recording; it prints the task reward, each agent's end and the episode's benchmark metrics. The
evaluation video's scenario is an informative one."""

from __future__ import annotations

import subprocess
import sys

import imageio_ffmpeg
import numpy as np
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from smarts.viz.recording import read_recording


def test_enjoy_writes_video_tensorboard_and_recording(tmp_path):
    video, tb, rec = tmp_path / "drive.mp4", tmp_path / "tb", tmp_path / "rec"
    cmd = [sys.executable, "-m", "train", "enjoy", "--agent", "zoo:keep-lane", "--scenario",
           "adaptive:a01_straight_free", "--max-steps", "40", "--video", str(video), "--tensorboard", str(tb),
           "--record", str(rec)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    # The task reward of the suite's task (adaptive: platoon), each agent's end, the benchmark's view.
    assert "episode 0: seed 0, 40 steps; return in platoon task reward: agent_0 +" in done.stdout
    assert "(still driving at the end)" in done.stdout and "benchmark metrics of this episode: PR" in done.stdout
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = reader.__next__()
    frames = [np.frombuffer(f, np.uint8) for f in reader]
    assert len(frames) == 40 and meta["fps"] == 10
    w, h = meta["size"]
    assert (w, h) == (640, 476) and frames[0].size == w * h * 3  # the follow camera's view, HUD and legend
    first = frames[0].reshape(h, w, 3).astype(int)
    # The followed agent in the middle of the road view (52 px of HUD above, 24 of legend below).
    centre = first[52 + 200 - 3 : 52 + 200 + 3, 320 - 8 : 320 + 8]
    assert (np.abs(centre - [230, 60, 50]).sum(axis=2) < 90).sum() > 20
    assert first[:48].mean() < first[60:420].mean() + 40 and first[:48].max() > 180  # the HUD's text on its band
    events = EventAccumulator(str(tb))
    events.Reload()
    (image,) = events.Images("enjoy/a01_straight_free")
    assert image.encoded_image_string[:6] == b"GIF89a"
    (path,) = rec.glob("*.rec.npz")
    assert read_recording(path).num_steps == 41


def test_enjoy_refuses_bad_options(tmp_path):
    cmd = [sys.executable, "-m", "train", "enjoy", "--agent", "zoo:keep-lane", "--scenario", "adaptive:nope"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 2 and "suite 'adaptive' has no scenario 'nope'" in done.stderr
    cmd[-1] = "adaptive:a01_straight_free"
    done = subprocess.run(cmd + ["--video", "x.avi"], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 2 and "expected a .mp4" in done.stderr


def test_evaluation_video_in_tensorboard(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    from train.enjoy import episode_frames, write_tensorboard_video

    frames = episode_frames("zoo:keep-lane", "adaptive:a01_straight_free", seed=3000, max_steps=20)
    assert len(frames) == 20 and frames[0].dtype == np.uint8 and frames[0].shape == (476, 640, 3)
    assert not np.array_equal(frames[0][52:452], frames[-1][52:452])  # the road moved under the camera
    with SummaryWriter(log_dir=str(tmp_path)) as writer:
        write_tensorboard_video(writer, "eval_video/a01_straight_free", frames, step=128)
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    (image,) = events.Images("eval_video/a01_straight_free")
    assert image.step == 128 and (image.width, image.height) == (frames[0].shape[1], frames[0].shape[0])


def test_evaluation_video_shows_a_scenario_with_a_junction_or_a_chosen_one():
    import pytest

    from smarts.benchmark.suites import load_suite
    from train.enjoy import video_scenario

    adaptive = load_suite("adaptive")
    assert video_scenario(adaptive).startswith("a04_")  # the first map with a junction: a lane change to an exit
    assert video_scenario(load_suite("collaborative")) == "c01_4way_1lane_left_free"  # a left turn
    assert video_scenario(adaptive, "a09_lead_turns_right_at_signal_medium") == "a09_lead_turns_right_at_signal_medium"
    with pytest.raises(ValueError, match="eval video scenario 'a99'"):
        video_scenario(adaptive, "a99")
