"""``python -m train enjoy``: watch a policy drive a scenario, or write it as a video.

    python -m train enjoy --agent zoo:keep-lane --scenario adaptive:a01_straight_free --video out.mp4
    python -m train enjoy --agent runs/train/platoon/latest --scenario adaptive:a08_lead_turns_left_at_junction --viz

The policy is loaded as the benchmark loads it (a ``zoo:`` locator, a checkpoint, or a training
run folder: its best.pt) and drives every learning agent of the scenario in its own action space.
Rewards are the task's (``smarts.env.task_rewards``): the reward a training run's ``config.json``
beside the checkpoint says, else the task of the scenario's suite (adaptive: platoon,
collaborative: drive), else ``--task``; ``--task scenario`` keeps the scenario's default reward.
Each episode's line says its steps, each agent's task return and how each agent's episode ended
(its end events, or still driving at the time limit).

``--video`` writes follow-camera frames (``smarts.viz.video``: the first agent, or ``--follow``,
at 6 px/m with a HUD of step, speed, task reward and events, and a colour legend), encoded with
the ffmpeg of the ``imageio-ffmpeg`` wheel (no system ffmpeg); ``--tensorboard`` adds the episode
as an animated image to a TensorBoard log; ``--viz`` starts the viewer in this process and
streams the episode to it live; ``--record`` keeps viewer recordings.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

DEFAULT_FPS = 10


def suite_entry(name: str):
    """``(suite, entry)`` of ``suite:scenario`` (a benchmark suite's scenario); ``(None, None)``
    for a library name or a YAML path."""
    if ":" not in name or Path(name).exists():
        return None, None
    from smarts.benchmark.suites import load_suite

    suite_name, scenario = name.split(":", 1)
    suite = load_suite(suite_name)
    for entry in suite.scenarios:
        if entry.name == scenario:
            return suite, entry
    raise ValueError(f"--scenario {name}: suite {suite_name!r} has no scenario {scenario!r}; "
                     f"it has {', '.join(s.name for s in suite.scenarios)}")  # fmt: skip


def scenario_spec(name: str):
    """A spec from ``suite:scenario`` (a benchmark suite scenario), a library name or a YAML path."""
    from smarts.scenario import load_scenario

    _, entry = suite_entry(name)
    return entry.spec if entry is not None else load_scenario(name)


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


SUITE_TASK = {"adaptive": "platoon", "collaborative": "drive"}
"""The training task whose reward fits each benchmark task."""


def task_reward(agent: str, scenario: str, task: str | None = None):
    """``(name, reward function or None)``: the task reward an episode of ``agent`` on
    ``scenario`` is told in (see the module docstring); None with ``task == "scenario"``."""
    from smarts.env.task_rewards import TaskReward

    if task == "scenario":
        return "the scenario's default", None
    config = Path(agent).parent / "config.json" if Path(agent).suffix == ".pt" else None
    if task is None and config is not None and config.is_file():  # the run's own reward
        from train.config import load_config

        cfg = load_config(None, config)
        return f"{cfg.reward_weights().task} task", TaskReward(cfg.reward_weights())
    if task is None and ":" in scenario and not Path(scenario).exists():
        from smarts.benchmark.suites import load_suite

        task = SUITE_TASK.get(load_suite(scenario.split(":", 1)[0]).task)
    if task is None:
        return "the scenario's default", None
    from train.config import load_config

    weights = load_config(task).reward_weights()
    return f"{weights.task} task", TaskReward(weights)


def policy_env(agent: str, scenario: str, seed: int = 0, task: str | None = None):
    """(policy, env, spec, reward name): the policy ``agent`` names, loaded as the benchmark
    loads it, and an env of ``scenario`` whose learning agents act in the policy's action space
    and whose rewards are :func:`task_reward`'s."""
    from smarts.benchmark.agents import agent_locator, load_policy, policy_setup, scenario_for
    from smarts.env import DrivingParallelEnv

    agent = agent_locator(agent)
    policy = load_policy(agent, seed)
    setup = policy_setup(policy, agent)
    spec = scenario_for(scenario_spec(scenario), setup)
    name, reward = task_reward(agent, scenario, task)
    env = DrivingParallelEnv(spec, observation=setup.interface, lane_relative=setup.lane_relative, reward=reward,
                             render_mode="rgb_array")  # fmt: skip
    return policy, env, spec, name


def act(policy, env, obs: dict) -> dict:
    """One batched policy call for every live agent."""
    batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
    return dict(zip(env.agents, np.asarray(policy.act(batch))))


class EpisodeFilm:
    """Follow-camera frames of one episode with its HUD (``smarts.viz.video``), and the task
    return and end of each agent, fed step by step."""

    def __init__(self, env, spec, reward_name: str, follow: str | None = None, draw: bool = True):
        from smarts.viz.video import FollowCamera

        self.env, self.reward_name = env, reward_name
        self.scenario = str(spec.name)
        self.follow = follow or env.possible_agents[0]
        if self.follow not in env.possible_agents:
            raise ValueError(f"--follow {self.follow}: not a learning agent of {self.scenario} "
                             f"({', '.join(env.possible_agents)})")  # fmt: skip
        self.camera = FollowCamera(env.sim, scenario=self.scenario) if draw else None
        self.returns = dict.fromkeys(env.possible_agents, 0.0)
        self.ended: dict[str, str] = {}
        self.env_said: dict[str, str] = {}  # what the env's events called an end the benchmark reads otherwise
        self.steps = 0
        self._last: tuple[float | None, list[str]] = (None, [])

    def frame(self) -> np.ndarray:
        from smarts.viz.video import hud_lines

        reward, events = self._last
        hud = hud_lines(self.env.sim, self.follow, scenario=self.scenario, step=self.steps, reward=reward,
                        total=self.returns[self.follow], reward_name=self.reward_name, events=events,
                        ended=self.ended.get(self.follow))  # fmt: skip
        return self.camera.frame(self.follow, hud)

    def after_step(self, rewards: dict, terminations: dict, truncations: dict, infos: dict) -> None:
        self.steps += 1
        for agent, value in rewards.items():
            self.returns[agent] += float(value)
        for agent in rewards:
            if terminations.get(agent) or truncations.get(agent):
                events = list(infos.get(agent, {}).get("events", []))
                self.ended[agent] = ", ".join(events) or ("time limit" if truncations.get(agent) else "done")
        me = self.follow
        self._last = (float(rewards[me]) if me in rewards else None, list(infos.get(me, {}).get("events", [])))

    def summary(self) -> str:
        """``agent_0 +12.34 (ended: off_road); agent_1 ...`` for every agent."""
        parts = []
        for agent, total in self.returns.items():
            end = self.ended.get(agent, "still driving at the end")
            said = f" (the env's events: {self.env_said[agent]})" if self.env_said.get(agent) else ""
            parts.append(f"{agent} {total:+.2f} ({'ended: ' + end if agent in self.ended else end}{said})")
        return "; ".join(parts)


def episode_frames(agent: str, scenario: str, seed: int = 0, max_steps: int | None = None,
                   follow: str | None = None) -> list[np.ndarray]:  # fmt: skip
    """The follow-camera frames (with HUD and legend) of one episode of ``agent`` on
    ``scenario``, the last after the final step (for an evaluation video:
    ``write_tensorboard_video(writer, tag, episode_frames(checkpoint, "adaptive:a04_...", ...), step)``)."""
    policy, env, spec, reward_name = policy_env(agent, scenario, seed)
    frames = []
    try:
        obs, _ = env.reset(seed=seed)
        film = EpisodeFilm(env, spec, reward_name, follow)
        while env.agents and (max_steps is None or film.steps < max_steps):
            frames.append(film.frame())
            obs, rewards, terminations, truncations, infos = env.step(act(policy, env, obs))
            film.after_step(rewards, terminations, truncations, infos)
        if max_steps is None or film.steps < max_steps:
            frames.append(film.frame())  # how it ended
    finally:
        env.close()
    return frames


def video_scenario(suite, chosen: str | None = None) -> str:
    """The scenario of ``suite`` an evaluation video shows: ``chosen`` when given (refused with the
    suite's names if it has none of that name), else the first whose map has a junction, a merge or
    an exit (internal junction lanes: where an agent turns, merges or changes lanes for an exit,
    which says more about a policy than an empty straight road), else the first."""
    names = [s.name for s in suite.scenarios]
    if chosen is not None:
        if chosen not in names:
            raise ValueError(f"eval video scenario {chosen!r}: suite {suite.name!r} has {', '.join(names)}")
        return chosen
    from smarts.env.assembly import scenario_map

    for entry in suite.scenarios:
        if scenario_map(entry.spec).lane_internal.any():
            return entry.name
    return names[0]


def enjoy(args: argparse.Namespace) -> int:
    """Play ``--episodes`` episodes of the agent, watched, filmed or recorded as asked, and print
    each one's returns (and benchmark metrics on a suite scenario)."""
    policy, env, spec, reward_name = policy_env(args.agent, args.scenario, args.seed, args.task)
    env, server = _watched(env, args)
    frames = _Frames(args)
    scoring = _Scoring(env, args.scenario)
    try:
        if args.viz and args.wait > 0:
            _wait_for_viewer(env, args.wait)
        for episode in range(args.episodes):
            _play_episode(env, policy, spec, reward_name, args, episode, frames, scoring)
    finally:
        frames.close()
        env.close()
        if server is not None:
            server.stop()
    if frames.video:
        print(f"video: {frames.video.path} ({frames.video.frames} frames at {args.fps} fps)")
    for path in getattr(env, "recordings", []):
        print(f"recording: {path}")
    return 0


def _watched(env, args: argparse.Namespace):
    """``env`` in the web viewer (``--viz``, live, waiting up to 10 s for the browser) and/or
    recorded (``--record``); the env and the viewer's server (None without ``--viz``)."""
    if not (args.viz or args.record):
        return env, None
    from smarts.viz.watch import WatchedEnv

    server = live = None
    if args.viz:
        from smarts.viz.server import BackgroundServer

        server = BackgroundServer(port=args.port)
        live = server.url
        print(f"viewer: {server.url}/?episode=live (open it in a browser; the episode starts when it connects)")
    env = WatchedEnv(env, record=args.record, live=live)
    if args.viz:
        env.publisher.connected.wait(10)
    return env, server


class _Frames:
    """Where the pictures of ``enjoy`` go: the ``--video`` file and one TensorBoard video per
    episode (``--tensorboard``); nothing is drawn without either."""

    def __init__(self, args: argparse.Namespace):
        self.fps = args.fps
        self.video = VideoWriter(args.video, args.fps) if args.video else None
        self.episode: list[np.ndarray] = []
        self.writer = None
        if args.tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(log_dir=str(args.tensorboard))
        self.drawing = bool(self.video or self.writer)

    def add(self, frame: np.ndarray | None) -> None:
        if self.video:
            self.video.add(frame)
        if self.writer:
            self.episode.append(frame)

    def end_episode(self, tag: str, episode: int) -> None:
        if self.writer:
            write_tensorboard_video(self.writer, tag, self.episode, episode, self.fps)
            self.episode = []

    def close(self) -> None:
        if self.video:
            self.video.close()
        if self.writer:
            self.writer.close()


class _Scoring:
    """A suite scenario is also scored as the benchmark scores it (its recorder and metrics), which
    also tells a vehicle that left the map at its route's end from one that left the road."""

    def __init__(self, env, scenario: str):
        self.suite, self.entry = suite_entry(scenario)
        self.now = None  # the recorder of the episode under way
        if self.entry is not None:
            env.add_step_listener(lambda sim: self.now.record() if self.now is not None else None)

    def start(self, env, episode: int, seed: int) -> None:
        if self.entry is None:
            return
        from smarts.benchmark.recorder import EpisodeRecorder

        entry = self.entry
        self.now = EpisodeRecorder(env.sim, env.possible_agents, scenario=entry.name, task=self.suite.task,
                                   episode=episode, seed=seed, time_limit=entry.time_limit, follow=entry.follow)  # fmt: skip

    def finish(self, film: EpisodeFilm) -> str | None:
        """The episode's benchmark metrics as one line (None off the suites)."""
        if self.entry is None:
            return None
        log, self.now = self.now.finish(), None
        return _benchmark_view(log, film)


def _play_episode(env, policy, spec, reward_name: str, args: argparse.Namespace, episode: int, frames: _Frames,
                  scoring: _Scoring) -> None:  # fmt: skip
    """One episode from seed ``args.seed + episode``, filmed into ``frames`` and, on a suite
    scenario, scored as the benchmark does."""
    seed = args.seed + episode
    obs, _ = env.reset(seed=seed)
    scoring.start(env, episode, seed)
    film = EpisodeFilm(env, spec, reward_name, args.follow, draw=frames.drawing)
    while env.agents and (args.max_steps is None or film.steps < args.max_steps):
        frames.add(film.frame() if frames.drawing else None)
        obs, rewards, terminations, truncations, infos = env.step(act(policy, env, obs))
        film.after_step(rewards, terminations, truncations, infos)
        if args.viz and args.realtime:
            import time

            time.sleep(spec.step_length)
    scores = scoring.finish(film)
    if frames.drawing and not env.agents:  # the last picture: how the episode ended
        frames.add(film.frame())
    frames.end_episode(f"enjoy/{spec.name}", episode)
    print(f"episode {episode}: seed {seed}, {film.steps} steps; return in {reward_name} reward: {film.summary()}")
    if scores is not None:
        print(f"  benchmark metrics of this episode: {scores}")


def _benchmark_view(log, film: EpisodeFilm) -> str:
    """The episode's benchmark metrics as one line; an agent that left the map at its route's end
    (the end-of-map rule, ``smarts.benchmark.metrics.scores``) is said to have, whatever the
    env's events called it."""
    from smarts.benchmark.metrics import metric_names, score_episode

    for agent, trace in log.agents.items():
        if trace.num_steps and trace.flag("left_map").any():
            film.env_said[agent] = film.ended.get(agent, "")
            film.ended[agent] = "left the map at its route's end"
    if not log.agents:
        return "none (no agent drove)"
    scores = score_episode(log)
    return ", ".join(f"{m} {scores[m]:.3f}" for m in metric_names(log.task))


def _wait_for_viewer(env, seconds: float) -> None:
    """Give a browser ``seconds`` to connect before the episode starts (a live view shows what
    happens from when it connects)."""
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not env.publisher.watching:
        time.sleep(0.1)


def add_options(p: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """The options of ``python -m train enjoy`` (its command is listed in ``train.__main__``)."""
    summary, examples = __doc__.split("\n\n")[:2]
    p.description = summary.split(": ", 1)[-1]  # the docstring's first line without its markup
    p.description = p.description[:1].upper() + p.description[1:]
    p.epilog = f"examples:\n{examples}"
    p.add_argument("--agent", required=True, help="zoo:<name>, a checkpoint .pt or a training run folder (its best.pt)")
    p.add_argument(
        "--scenario", required=True, help="suite:scenario (adaptive:a01_straight_free), a library name or a YAML file"
    )
    p.add_argument("--episodes", type=int, default=1, help="episodes to run")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument(
        "--max-steps", type=int, default=None, help="stop an episode after this many steps (default: its end)"
    )
    p.add_argument("--video", type=Path, default=None, help="write the episodes to this .mp4")
    p.add_argument("--fps", type=int, default=DEFAULT_FPS, help="video frames per second")
    p.add_argument(
        "--tensorboard", type=Path, default=None, help="add each episode as a video to this TensorBoard log folder"
    )
    p.add_argument("--viz", action="store_true", help="serve the viewer here (127.0.0.1) and stream the episodes to it")
    p.add_argument("--port", type=int, default=8765, help="viewer port with --viz")
    p.add_argument("--wait", type=float, default=60.0, help="with --viz: seconds to wait for a browser first")
    p.add_argument("--realtime", action=argparse.BooleanOptionalAction, default=True,
                   help="with --viz: run at the scenario's own step rate")  # fmt: skip
    p.add_argument(
        "--record", type=Path, default=None, help="also write viewer recordings of the episodes to this folder"
    )
    p.add_argument("--task", choices=["platoon", "drive", "scenario"], default=None,
                   help="the reward told: a training task's, or the scenario's default (default: the run's own from "
                        "the config.json beside a checkpoint, else the suite's task)")  # fmt: skip
    p.add_argument(
        "--follow", default=None, metavar="AGENT", help="the agent the video camera follows (default: the first)"
    )
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
