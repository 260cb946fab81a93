"""The episode recording: every road user, signal and agent of every step, in one compact file.

Benchmark episode logs hold only what the metrics need (the agents' traces); a recording holds
what the viewer shows: all vehicles, the signal colours, each agent's action, reward, events,
observed neighbours and waypoints, and the map's drawable description, so it can be viewed
without the map file.

On disk: one compressed ``.npz`` (never pickled). ``metadata`` is a JSON string (format name and
version, scenario, seed, dt, agent ids, vehicle ids, event names, vehicle columns), ``scene`` the
map description (``smarts.viz.scene``) as JSON. Step ``k`` (0 is the reset state) has time
``time[k]``; its vehicles are rows ``vehicle_offsets[k]:vehicle_offsets[k + 1]`` of the flat
``vehicle_*`` arrays (``vehicle_index`` into the metadata's ``vehicle_ids``). Per step and agent
(in ``agent_ids`` order): ``agent_vehicle`` (row within the step's vehicles, -1 when the agent is
not on the road), ``agent_reward`` and ``agent_action`` (NaN at the reset state),
``agent_events`` (bool per event name), ``agent_neighbours`` [K, 3] (map x, y, visible
fraction; NaN rows pad) and ``agent_waypoints`` [paths, W, 2] (map x, y; NaN where absent).
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from smarts.cache import atomic_write_bytes
from smarts.core.errors import LogError
from smarts.viz.capture import EVENTS, VEHICLE_COLUMNS, Frame, frame_json
from smarts.viz.schema import Scene, describe

FORMAT_NAME = "smarts-recording"
FORMAT_VERSION = 1
SUFFIX = ".rec.npz"

_ARRAYS = {
    "time": (np.float64, 1),
    "vehicle_offsets": (np.int64, 1),
    "vehicle_index": (np.int32, 1),
    "vehicle_state": (np.float32, 2),
    "vehicle_role": (np.int8, 1),
    "vehicle_lane": (np.int32, 1),
    "signal_colour": (np.int8, 2),
    "agent_vehicle": (np.int32, 2),
    "agent_reward": (np.float32, 2),
    "agent_action": (np.float32, 3),
    "agent_events": (bool, 3),
    "agent_neighbours": (np.float32, 4),
    "agent_waypoints": (np.float32, 5),
}


@dataclass
class Recording:
    """One recorded episode (see the module docstring for the arrays)."""

    meta: dict[str, Any]
    scene: dict[str, Any]
    arrays: dict[str, np.ndarray]
    source: str | None = None

    @property
    def num_steps(self) -> int:
        return len(self.arrays["time"])

    @property
    def agent_ids(self) -> list[str]:
        return list(self.meta["agent_ids"])

    def frame(self, k: int) -> Frame:
        """Step ``k`` as a frame (the layout ``StepCapture`` builds)."""
        a = self.arrays
        lo, hi = int(a["vehicle_offsets"][k]), int(a["vehicle_offsets"][k + 1])
        names = self.meta["vehicle_ids"]
        ids = [names[i] for i in a["vehicle_index"][lo:hi].tolist()]
        agents = {}
        for j, agent in enumerate(self.agent_ids):
            v = int(a["agent_vehicle"][k, j])
            if v < 0:
                continue
            action = a["agent_action"][k, j]
            reward = float(a["agent_reward"][k, j])
            nb = a["agent_neighbours"][k, j]
            agents[agent] = {
                "vehicle": ids[v],
                "action": None if np.isnan(action).all() else action[~np.isnan(action)],
                "reward": None if np.isnan(reward) else reward,
                "events": [EVENTS[e] for e in np.flatnonzero(a["agent_events"][k, j])],
                "neighbours": nb[~np.isnan(nb[:, 0])],
                "waypoints": a["agent_waypoints"][k, j],
            }
        return {
            "time": float(a["time"][k]),
            "vehicle_ids": ids,
            "vehicle_state": a["vehicle_state"][lo:hi],
            "vehicle_role": a["vehicle_role"][lo:hi],
            "vehicle_lane": a["vehicle_lane"][lo:hi],
            "signal_colour": a["signal_colour"][k],
            "agent_vehicle": a["agent_vehicle"][k],
            "agents": agents,
        }

    def page_json(self) -> dict[str, Any]:
        """What the page loads: metadata, the map and every frame."""
        return {
            "kind": "recording",
            "meta": {**self.meta, "source": self.source},
            "scene": self.scene,
            "frames": [frame_json(self.frame(k), k) for k in range(self.num_steps)],
        }


def _pad(values: list[np.ndarray], shape_tail: tuple[int, ...], dtype) -> np.ndarray:
    out = np.full((len(values), *shape_tail), np.nan, dtype=dtype)
    for i, v in enumerate(values):
        if v is not None and np.size(v):
            v = np.asarray(v)
            out[(i, *tuple(slice(0, n) for n in v.shape))] = v
    return out


def build_recording(frames: list[Frame], agent_ids: list[str], scene: dict, meta: dict[str, Any]) -> Recording:
    """Stack captured frames (the first is the reset state) into a recording."""
    if not frames:
        raise ValueError("a recording needs at least the reset frame")
    id_index: dict[str, int] = {}
    vehicle_index = []
    for f in frames:
        vehicle_index.append(np.array([id_index.setdefault(str(v), len(id_index)) for v in f["vehicle_ids"]], np.int32))
    counts = [len(f["vehicle_ids"]) for f in frames]
    n_agents = len(agent_ids)
    t = len(frames)
    per_agent = [[f.get("agents", {}).get(a, {}) for a in agent_ids] for f in frames]

    def longest(key: str, axis: int) -> int:
        sizes = [np.shape(e[key])[axis] for row in per_agent for e in row if e.get(key) is not None and key in e]
        return max(sizes, default=0)

    action_dim = longest("action", 0)
    k_nb = longest("neighbours", 0)
    n_paths, n_wp = longest("waypoints", 0), longest("waypoints", 1)
    actions = np.full((t, n_agents, action_dim), np.nan, np.float32)
    rewards = np.full((t, n_agents), np.nan, np.float32)
    events = np.zeros((t, n_agents, len(EVENTS)), bool)
    neighbours = np.full((t, n_agents, k_nb, 3), np.nan, np.float32)
    waypoints = np.full((t, n_agents, n_paths, n_wp, 2), np.nan, np.float32)
    for i, row in enumerate(per_agent):
        for j, e in enumerate(row):
            if e.get("action") is not None:
                actions[i, j, : len(e["action"])] = e["action"]
            if e.get("reward") is not None:
                rewards[i, j] = e["reward"]
            for name in e.get("events", []):
                events[i, j, EVENTS.index(name)] = True
            if e.get("neighbours") is not None and len(e["neighbours"]):
                neighbours[i, j, : len(e["neighbours"])] = e["neighbours"]
            if e.get("waypoints") is not None and np.size(e["waypoints"]):
                wp = e["waypoints"]
                waypoints[i, j, : wp.shape[0], : wp.shape[1]] = wp
    n_signals = max((len(f["signal_colour"]) for f in frames), default=0)
    arrays = {
        "time": np.array([f["time"] for f in frames], np.float64),
        "vehicle_offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        "vehicle_index": np.concatenate(vehicle_index) if vehicle_index else np.zeros(0, np.int32),
        "vehicle_state": np.concatenate([np.asarray(f["vehicle_state"], np.float32).reshape(-1, 6) for f in frames]),
        "vehicle_role": np.concatenate([np.asarray(f["vehicle_role"], np.int8) for f in frames]),
        "vehicle_lane": np.concatenate([np.asarray(f["vehicle_lane"], np.int32) for f in frames]),
        "signal_colour": _pad([f["signal_colour"] for f in frames], (n_signals,), np.float64).astype(np.int8)
        if n_signals
        else np.zeros((t, 0), np.int8),
        "agent_vehicle": np.stack([np.asarray(f["agent_vehicle"], np.int32) for f in frames]).reshape(t, n_agents),
        "agent_reward": rewards,
        "agent_action": actions,
        "agent_events": events,
        "agent_neighbours": neighbours,
        "agent_waypoints": waypoints,
    }
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        **meta,
        "agent_ids": list(agent_ids),
        "vehicle_ids": list(id_index),
        "events": EVENTS,
        "vehicle_columns": list(VEHICLE_COLUMNS),
    }
    return Recording(meta=meta, scene=scene, arrays=arrays)


def write_recording(recording: Recording, path: str | os.PathLike) -> Path:
    """Write ``recording`` as one compressed ``.npz`` (atomically); returns the path."""
    path = Path(path)
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        metadata=np.array(json.dumps(recording.meta, allow_nan=False)),
        scene=np.array(json.dumps(recording.scene, allow_nan=False)),
        **recording.arrays,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def read_recording(path: str | os.PathLike) -> Recording:
    """Read and check one recording; ``LogError`` names the file and the array or field at fault."""
    src = str(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise LogError(f"not a readable .npz episode recording ({exc})", source=src) from None
    for name in ("metadata", "scene"):
        if name not in data:
            raise LogError(f"missing the {name!r} entry; not an episode recording", source=src, column=name)
    scene_text = str(data.pop("scene"))
    try:
        meta = json.loads(str(data.pop("metadata")))
        scene = json.loads(scene_text)
    except (ValueError, RecursionError) as exc:
        raise LogError(f"metadata or scene is not valid JSON ({exc})", source=src) from None
    try:  # the page draws it as it is: the same checks as a live env's map
        Scene.model_validate_json(scene_text)
    except ValidationError as exc:
        raise LogError(f"scene.{describe(exc)}", source=src, column="scene") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise LogError(f"metadata format is {meta.get('format') if isinstance(meta, dict) else meta!r}, expected "
                       f"{FORMAT_NAME!r}", source=src, column="metadata")  # fmt: skip
    if meta.get("version") != FORMAT_VERSION:
        raise LogError(f"version {meta.get('version')!r}; this viewer reads version {FORMAT_VERSION}",
                       source=src, column="metadata")  # fmt: skip
    for key in ("agent_ids", "vehicle_ids", "events"):
        if not isinstance(meta.get(key), list) or not all(isinstance(v, str) for v in meta[key]):
            raise LogError(f"metadata field {key!r} must be a list of strings", source=src, column="metadata")
    if not isinstance(meta.get("scenario"), str):
        raise LogError("metadata field 'scenario' must be a string", source=src, column="metadata")
    _check_arrays(data, meta, src)
    return Recording(meta=meta, scene=scene, arrays=data, source=src)


def _check_arrays(data: dict[str, np.ndarray], meta: dict, src: str) -> None:
    for name, (dtype, ndim) in _ARRAYS.items():
        if name not in data:
            raise LogError("missing array", source=src, column=name)
        if data[name].ndim != ndim or data[name].dtype != np.dtype(dtype):
            raise LogError(f"expected a {ndim}-D {np.dtype(dtype).name} array, got {data[name].ndim}-D "
                           f"{data[name].dtype.name}", source=src, column=name)  # fmt: skip
    t = len(data["time"])
    if t == 0:
        raise LogError("no steps", source=src, column="time")
    offsets = data["vehicle_offsets"]
    n = len(data["vehicle_index"])
    if len(offsets) != t + 1 or offsets[0] != 0 or offsets[-1] != n or np.any(np.diff(offsets) < 0):
        raise LogError(f"expected {t + 1} non-decreasing offsets from 0 to {n}", source=src, column="vehicle_offsets")
    for name in ("vehicle_state", "vehicle_role", "vehicle_lane"):
        if len(data[name]) != n:
            raise LogError(f"expected {n} rows like vehicle_index, got {len(data[name])}", source=src, column=name)
    if data["vehicle_state"].shape[1] != len(VEHICLE_COLUMNS):
        raise LogError(f"expected {len(VEHICLE_COLUMNS)} columns ({', '.join(VEHICLE_COLUMNS)})",
                       source=src, column="vehicle_state")  # fmt: skip
    if n and (data["vehicle_index"].min() < 0 or data["vehicle_index"].max() >= len(meta["vehicle_ids"])):
        raise LogError("an index outside the metadata's vehicle_ids", source=src, column="vehicle_index")
    n_agents = len(meta["agent_ids"])
    for name in (
        "agent_vehicle",
        "agent_reward",
        "agent_action",
        "agent_events",
        "agent_neighbours",
        "agent_waypoints",
    ):
        if data[name].shape[:2] != (t, n_agents):
            raise LogError(
                f"expected {t} steps x {n_agents} agents, got shape {data[name].shape}", source=src, column=name
            )
    counts = np.diff(offsets)
    v = data["agent_vehicle"]
    if np.any(v >= counts[:, None]) or np.any(v < -1):
        raise LogError("a vehicle row outside its step's vehicles", source=src, column="agent_vehicle")
    if data["agent_events"].shape[2] != len(EVENTS):
        raise LogError(f"expected {len(EVENTS)} events ({', '.join(EVENTS)})", source=src, column="agent_events")
    if len(data["signal_colour"]) != t:
        raise LogError(f"expected {t} rows", source=src, column="signal_colour")
