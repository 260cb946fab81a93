"""python -m train enjoy: a zoo policy drives a suite scenario into an MP4 (imageio-ffmpeg's own
ffmpeg), a TensorBoard animated image and a viewer recording."""

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
    assert "episode 0: seed 0, 40 steps" in done.stdout
    reader = imageio_ffmpeg.read_frames(str(video))
    meta = reader.__next__()
    frames = [np.frombuffer(f, np.uint8) for f in reader]
    assert len(frames) == 40 and meta["fps"] == 10
    w, h = meta["size"]
    assert frames[0].size == w * h * 3 and frames[0].std() > 5  # a drawn road, not a blank frame
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
    assert len(frames) == 20 and frames[0].dtype == np.uint8 and frames[0].ndim == 3
    assert not np.array_equal(frames[0], frames[-1])  # the vehicles moved
    with SummaryWriter(log_dir=str(tmp_path)) as writer:
        write_tensorboard_video(writer, "eval_video/a01_straight_free", frames, step=128)
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    (image,) = events.Images("eval_video/a01_straight_free")
    assert image.step == 128 and (image.width, image.height) == (frames[0].shape[1], frames[0].shape[0])
