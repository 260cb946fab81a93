"""``WatchedEnv``: a ``DrivingParallelEnv`` that records its episodes and/or streams them live.

    env = WatchedEnv(DrivingParallelEnv("intersection_4way_left"), record="runs/rec", live=True)

Used exactly like the env it wraps (every other attribute is the env's). ``record``: a folder;
each finished episode is written there as ``<scenario>__seed<seed>__<n>.rec.npz``
(``smarts.viz.recording``). ``live``: True or a viewer address (``smarts viz`` without a path
waits for live envs at http://127.0.0.1:8765); frames are built only while a browser is watching,
so an unwatched run is not slowed.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from smarts.viz.capture import ROLE_NAMES, Frame, StepCapture, action_fields, frame_json
from smarts.viz.live import DEFAULT_URL, LivePublisher
from smarts.viz.recording import SUFFIX, build_recording, write_recording
from smarts.viz.scene import map_scene


class WatchedEnv:
    """Records and/or streams the episodes of ``env`` (see the module docstring)."""

    def __init__(self, env: Any, *, record: str | Path | None = None, live: bool | str | None = None):
        self.env = env
        self.record_dir = Path(record) if record is not None else None
        self.publisher = LivePublisher(DEFAULT_URL if live is True else str(live)) if live else None
        self.capture = StepCapture(env)
        self.scene = map_scene(env.sim.road_map)
        self.recordings: list[Path] = []
        self._frames: list[Frame] = []
        self._meta: dict[str, Any] = {}
        self._episode = 0
        self._step = 0
        env.add_step_listener(self._on_step)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    @property
    def _capturing(self) -> bool:
        return self.record_dir is not None or (self.publisher is not None and self.publisher.watching)

    def _on_step(self, sim: Any) -> None:
        if self._capturing:
            self.capture.on_step(sim)

    def reset(self, seed: int | None = None, options: dict | None = None):
        self._save()
        obs, infos = self.env.reset(seed=seed, options=options)
        sim = self.env.sim
        self._episode += 1
        self._step = 0
        self._meta = {
            "scenario": str(self.env.scenario.name),
            "seed": int(sim.seed),
            "dt": float(sim.dt),
            "episode": self._episode,
            "roles": list(ROLE_NAMES),
            "action_fields": action_fields(self.env.scenario),
        }
        if self.publisher is not None:
            self.publisher.episode({**self._meta, "agent_ids": list(self.capture.agent_ids), "live": True}, self.scene)
        if self._capturing:
            self._keep(self.capture.reset_frame(obs))
        return obs, infos

    def step(self, actions: dict):
        result = self.env.step(actions)
        self._step += 1
        if self._capturing:
            obs, rewards, _, _, infos = result
            self._keep(self.capture.step_frame(actions, obs, rewards, infos))
        if self.record_dir is not None and not self.env.agents:
            self._save()
        return result

    def _keep(self, frame: Frame) -> None:
        if self.record_dir is not None:
            self._frames.append(frame)
        if self.publisher is not None and self.publisher.watching:
            self.publisher.frame(frame_json(frame, self._step))

    def _save(self) -> None:
        """Write the episode recorded so far (if any) to the record folder."""
        if self.record_dir is None or not self._frames:
            return
        recording = build_recording(self._frames, self.capture.agent_ids, self.scene, self._meta)
        name = re.sub(r"[^A-Za-z0-9_.-]+", "_", self._meta["scenario"])
        path = self.record_dir / f"{name}__seed{self._meta['seed']}__{self._episode:03d}{SUFFIX}"
        self.recordings.append(write_recording(recording, path))
        self._frames = []

    def close(self) -> None:
        self._save()
        if self.publisher is not None:
            self.publisher.close()
        self.env.close()
