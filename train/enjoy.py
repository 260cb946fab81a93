"""``python -m train enjoy``: watch a policy drive a scenario, or write it as a video.

    python -m train enjoy --agent zoo:keep-lane --scenario adaptive:a01_straight_free --video out.mp4
    python -m train enjoy --agent runs/train/platoon/latest/best.pt --scenario adaptive:a01_straight_free --viz

The policy is loaded as the benchmark loads it (a ``zoo:`` locator or a checkpoint) and drives
every learning agent of the scenario in its own action space. ``--video`` encodes the top-down
frames with the ffmpeg of the ``imageio-ffmpeg`` wheel (no system ffmpeg); ``--tensorboard``
adds the episode as an animated image to a TensorBoard log; ``--viz`` starts the viewer in this
process and streams the episode to it live; ``--record`` keeps viewer recordings.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

DEFAULT_FPS = 10


def scenario_spec(name: str):
    """A spec from ``suite:scenario`` (a benchmark suite scenario), a library name or a YAML path."""
    from smarts.scenario import load_scenario

    if ":" in name and not Path(name).exists():
        from smarts.benchmark.suites import load_suite

        suite_name, scenario = name.split(":", 1)
        suite = load_suite(suite_name)
        for entry in suite.scenarios:
            if entry.name == scenario:
                return entry.spec
        raise ValueError(f"--scenario {name}: suite {suite_name!r} has no scenario {scenario!r}; "
                         f"it has {', '.join(s.name for s in suite.scenarios)}")  # fmt: skip
    return load_scenario(name)


def even_frame(frame: np.ndarray) -> np.ndarray:
    """The frame padded to even height and width (H.264 in yuv420p needs both even)."""
    h, w = frame.shape[:2]
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge") if h % 2 or w % 2 else frame


class VideoWriter:
    """An MP4 (H.264) written frame by frame through imageio-ffmpeg's bundled ffmpeg."""

    def __init__(self, path: str | Path, fps: int = DEFAULT_FPS):
        self.path = Path(path)
        self.fps = fps
        self._writer = None
        self.frames = 0

    def add(self, frame: np.ndarray) -> None:
        import imageio_ffmpeg

        frame = even_frame(np.ascontiguousarray(frame, dtype=np.uint8))
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            h, w = frame.shape[:2]
            self._writer = imageio_ffmpeg.write_frames(
                str(self.path), (w, h), fps=self.fps, codec="libx264", pix_fmt_out="yuv420p",
                macro_block_size=1, quality=7, ffmpeg_log_level="error",
            )  # fmt: skip
            self._writer.send(None)  # start ffmpeg
            self._size = (h, w)
        if frame.shape[:2] != self._size:
            raise ValueError(f"video frames must keep one size: {self._size}, got {frame.shape[:2]}")
        self._writer.send(frame)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def write_tensorboard_video(writer, tag: str, frames: list[np.ndarray], step: int, fps: int = DEFAULT_FPS) -> None:
    """Add ``frames`` (uint8 [H, W, 3]) to a ``SummaryWriter`` as an animated GIF image, which
    TensorBoard's Images tab plays (what ``add_video`` writes, without its moviepy dependency)."""
    from PIL import Image
    from tensorboard.compat.proto.summary_pb2 import Summary

    if not frames:
        return
    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    h, w = frames[0].shape[:2]
    image = Summary.Image(height=h, width=w, colorspace=3, encoded_image_string=buffer.getvalue())
    writer._get_file_writer().add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]), step)
    writer.flush()


def policy_env(agent: str, scenario: str, seed: int = 0):
    """(policy, env, spec): the policy ``agent`` names, loaded as the benchmark loads it, and a
    rendering env of ``scenario`` whose learning agents act in the policy's action space."""
    from smarts.benchmark.runner import load_policy, policy_setup, scenario_for
    from smarts.env import DrivingParallelEnv

    policy = load_policy(agent, seed)
    setup = policy_setup(policy, agent)
    spec = scenario_for(scenario_spec(scenario), setup)
    env = DrivingParallelEnv(spec, observation=setup.interface, lane_relative=setup.lane_relative,
                             render_mode="rgb_array")  # fmt: skip
    return policy, env, spec


def act(policy, env, obs: dict) -> dict:
    """One batched policy call for every live agent."""
    batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
    return dict(zip(env.agents, np.asarray(policy.act(batch))))


def episode_frames(agent: str, scenario: str, seed: int = 0, max_steps: int | None = None) -> list[np.ndarray]:
    """The top-down frames of one episode of ``agent`` on ``scenario`` (for an evaluation video:
    ``write_tensorboard_video(writer, tag, episode_frames(checkpoint, "adaptive:a01_straight_free"), step)``)."""
    policy, env, _ = policy_env(agent, scenario, seed)
    frames = []
    try:
        obs, _ = env.reset(seed=seed)
        while env.agents and (max_steps is None or len(frames) < max_steps):
            frames.append(env.render())
            obs, *_ = env.step(act(policy, env, obs))
    finally:
        env.close()
    return frames


def enjoy(args: argparse.Namespace) -> int:
    policy, env, spec = policy_env(args.agent, args.scenario, args.seed)
    server = None
    if args.viz or args.record:
        from smarts.viz.watch import WatchedEnv

        live = None
        if args.viz:
            from smarts.viz.server import BackgroundServer

            server = BackgroundServer(port=args.port)
            live = server.url
            print(f"viewer: {server.url}/?episode=live (open it in a browser; the episode starts when it connects)")
        env = WatchedEnv(env, record=args.record, live=live)
        if args.viz:
            env.publisher.connected.wait(10)
    video = VideoWriter(args.video, args.fps) if args.video else None
    tb_frames: list[np.ndarray] = []
    writer = None
    if args.tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(log_dir=str(args.tensorboard))
    try:
        if args.viz and args.wait > 0:
            _wait_for_viewer(env, args.wait)
        for episode in range(args.episodes):
            obs, _ = env.reset(seed=args.seed + episode)
            steps = 0
            total = 0.0
            while env.agents and (args.max_steps is None or steps < args.max_steps):
                frame = env.render() if (video or writer) else None
                if video:
                    video.add(frame)
                if writer:
                    tb_frames.append(frame)
                obs, rewards, *_ = env.step(act(policy, env, obs))
                total += sum(rewards.values())
                steps += 1
                if args.viz and args.realtime:
                    import time

                    time.sleep(spec.step_length)
            if writer:
                write_tensorboard_video(writer, f"enjoy/{spec.name}", tb_frames, episode, args.fps)
                tb_frames = []
            print(f"episode {episode}: seed {args.seed + episode}, {steps} steps, return {total:.2f}")
    finally:
        if video:
            video.close()
        if writer:
            writer.close()
        env.close()
        if server is not None:
            server.stop()
    if video:
        print(f"video: {video.path} ({video.frames} frames at {args.fps} fps)")
    for path in getattr(env, "recordings", []):
        print(f"recording: {path}")
    return 0


def _wait_for_viewer(env, seconds: float) -> None:
    """Give a browser ``seconds`` to connect before the episode starts (a live view shows what
    happens from when it connects)."""
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not env.publisher.watching:
        time.sleep(0.1)


def add_parser(sub) -> None:
    """Register ``enjoy`` on the ``python -m train`` command line."""
    p = sub.add_parser("enjoy", help="watch a policy drive a scenario (browser, video or TensorBoard)",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("--agent", required=True, help="zoo:<name> or a checkpoint .pt")
    p.add_argument("--scenario", required=True, help="suite:scenario (adaptive:a01_straight_free), a library name or a YAML file")
    p.add_argument("--episodes", type=int, default=1, help="episodes to run (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    p.add_argument("--max-steps", type=int, default=None, help="stop an episode after this many steps (default: its end)")
    p.add_argument("--video", type=Path, default=None, help="write the episodes to this .mp4")
    p.add_argument("--fps", type=int, default=DEFAULT_FPS, help=f"video frames per second (default {DEFAULT_FPS})")
    p.add_argument("--tensorboard", type=Path, default=None, help="add each episode as a video to this TensorBoard log folder")
    p.add_argument("--viz", action="store_true", help="serve the viewer here (127.0.0.1) and stream the episodes to it")
    p.add_argument("--port", type=int, default=8765, help="viewer port with --viz (default 8765)")
    p.add_argument("--wait", type=float, default=60.0, help="with --viz: seconds to wait for a browser first (default 60)")
    p.add_argument("--realtime", action=argparse.BooleanOptionalAction, default=True,
                   help="with --viz: run at the scenario's own step rate (default on)")  # fmt: skip
    p.add_argument("--record", type=Path, default=None, help="also write viewer recordings of the episodes to this folder")
    p.set_defaults(run=_run)


def _run(args: argparse.Namespace) -> int:
    for name in ("episodes", "fps"):
        if getattr(args, name) < 1:
            print(f"error: --{name} must be >= 1", file=sys.stderr)
            return 2
    if args.video is not None and args.video.suffix.lower() != ".mp4":
        print(f"error: --video {args.video}: expected a .mp4 file name", file=sys.stderr)
        return 2
    return enjoy(args)
