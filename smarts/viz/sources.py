"""Recorded episodes the viewer can open: episode recordings and benchmark episode logs.

A path is one file or a folder searched for ``*.npz`` below it (a benchmark run's ``logs``
folder, a folder of recordings, or both). A recording carries everything, the map included. A
benchmark log holds the agents' traces and no traffic; its map comes from the benchmark suite
scenario it names (the suite is the folder the run wrote, ``runs/benchmark/<suite>/logs/...``, or
the built-in suite of the log's task), and its per-agent benchmark metrics are computed from the
log itself.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from smarts.core.errors import LogError
from smarts.core.vehicle_table import Role
from smarts.viz.recording import FORMAT_NAME as RECORDING_FORMAT
from smarts.viz.recording import read_recording
from smarts.viz.scene import map_scene


@dataclass(frozen=True)
class EpisodeEntry:
    """One openable episode: ``kind`` is ``recording`` or ``log``."""

    path: Path
    kind: str
    name: str


def find_episodes(path: str | Path, on_skip: Callable[[Path, str], None] | None = None) -> list[EpisodeEntry]:
    """The recordings and benchmark logs at ``path`` (a file, or every ``*.npz`` below a folder),
    sorted by path. A missing path, or a named file that is neither, is a ``LogError`` naming it;
    in a folder, such a file is skipped and ``on_skip(file, problem)`` told why."""
    root = Path(path)
    if not root.exists():
        raise LogError("no such file or folder", source=str(root))
    files = sorted(root.rglob("*.npz")) if root.is_dir() else [root]
    out = []
    for f in files:
        kind, problem = episode_kind(f)
        if kind is None:
            if root.is_file():
                raise LogError(problem, source=str(f))
            if on_skip is not None:
                on_skip(f, problem)
            continue
        out.append(EpisodeEntry(f, kind, str(f.relative_to(root)) if root.is_dir() else f.name))
    return out


NEITHER = "neither an episode recording nor a benchmark episode log"


def episode_kind(path: Path) -> tuple[str | None, str]:
    """``("recording" | "log", "")`` from a file's metadata alone, or ``(None, what is wrong)``."""
    from smarts.benchmark.metrics.log import FORMAT_NAME as LOG_FORMAT

    try:
        with np.load(path, allow_pickle=False) as npz:
            if "metadata" not in npz.files:
                return None, f"{NEITHER} (no 'metadata' entry)"
            text, has_scene = str(npz["metadata"]), "scene" in npz.files
    except Exception as exc:  # any file that cannot be read is skipped (a viewer of a folder must start)
        return None, f"{NEITHER} (not a readable .npz: {type(exc).__name__}: {str(exc)[:200]})"
    try:
        meta = json.loads(text)
    except (ValueError, RecursionError) as exc:
        return None, f"{NEITHER} (metadata is not valid JSON: {str(exc)[:200]})"
    if not isinstance(meta, dict):
        return None, f"{NEITHER} (metadata is a JSON {_json_kind(meta)}, expected an object)"
    fmt = meta.get("format")
    if fmt == RECORDING_FORMAT and has_scene:
        return "recording", ""
    if fmt == LOG_FORMAT:
        return "log", ""
    return None, f"{NEITHER} (metadata format {str(fmt)[:100]!r})"


def _json_kind(value: Any) -> str:
    return {list: "list", str: "string", bool: "boolean", int: "number", float: "number"}.get(type(value), "null")


def episode_json(entry: EpisodeEntry) -> bytes:
    """The page's JSON of one episode (cached: the same file is not converted twice)."""
    stat = entry.path.stat()
    return _episode_json(str(entry.path), entry.kind, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=8)
def _episode_json(path: str, kind: str, mtime: int, size: int) -> bytes:
    data = read_recording(path).page_json() if kind == "recording" else log_page_json(Path(path))
    return json.dumps(data, allow_nan=False, separators=(",", ":")).encode()


# ---------------------------------------------------------------------------------- benchmark logs
def _suite_entry(log_path: Path, scenario: str, task: str):
    """The suite scenario a log was run on: the suite named by the run folder, else the built-in
    suite of the log's task."""
    from smarts.benchmark.suites import load_suite, suite_names

    candidates = [p.parent.name for p in log_path.parents if p.name == "logs"]
    candidates += [task] + suite_names()
    tried = []
    for name in dict.fromkeys(candidates):
        if name not in suite_names():
            continue
        tried.append(name)
        for entry in load_suite(name).scenarios:
            if entry.name == scenario:
                return entry
    raise LogError(f"scenario {scenario!r} is in none of the benchmark suites {tried}; cannot draw its map",
                   source=str(log_path), column="scenario")  # fmt: skip


def log_page_json(path: Path) -> dict[str, Any]:
    """A benchmark log as the page's episode: the suite scenario's map, the agents' traces as
    vehicles (no traffic: the log has none), and each agent's benchmark metrics."""
    from smarts.benchmark.metrics.log import read_episode
    from smarts.benchmark.metrics.scores import agent_costs, score_episode
    from smarts.env.assembly import scenario_map

    log = read_episode(path)
    entry = _suite_entry(path, log.scenario, log.task)
    scene = map_scene(scenario_map(entry.spec))
    dims = {a.id: a.vehicle.dimensions() for a in entry.spec.agents}
    metrics: dict[str, Any] = {"episode": score_episode(log) if log.agents or log.failed else {}}
    metrics["agents"] = {a: c.as_dict() for a, c in agent_costs(log).items()} if log.agents else {}
    times = sorted({round(float(t), 6) for tr in log.agents.values() for t in tr.time})
    frames = []
    for k, t in enumerate(times):
        frame: dict[str, Any] = {"step": k + 1, "t": t, "ids": [], "x": [], "y": [], "h": [], "speed": [],
                                 "length": [], "width": [], "role": [], "lane": [], "signals": [], "agents": {}}  # fmt: skip
        for agent, tr in log.agents.items():
            hit = np.flatnonzero(np.abs(tr.time - t) < 1e-6)
            if not hit.size:
                continue
            i = int(hit[0])
            d = dims.get(agent)
            frame["ids"].append(agent)
            frame["x"].append(round(float(tr.x[i]), 2))
            frame["y"].append(round(float(tr.y[i]), 2))
            frame["h"].append(round(float(tr.heading[i]), 3))
            frame["speed"].append(round(float(tr.speed[i]), 2))
            frame["length"].append(d.length if d else 4.6)
            frame["width"].append(d.width if d else 1.9)
            frame["role"].append(int(Role.AGENT))
            frame["lane"].append(-1)
            state = {c: _json_number(v[i]) for c, v in tr.columns().items()}
            events = [c for c in ("wrong_way", "partial_off_road", "off_road", "goal_reached") if state.get(c)]
            frame["agents"][agent] = {"vehicle": agent, "action": None, "reward": None, "events": events,
                                      "neighbours": [], "waypoints": [], "log": state}  # fmt: skip
        frames.append(frame)
    meta = {
        "scenario": log.scenario, "task": log.task, "episode": log.episode, "seed": log.seed, "dt": log.dt,
        "agent_ids": log.agent_ids, "failure": log.failure, "info": log.info, "source": str(path),
        "note": "a benchmark log holds the agents' traces only: no traffic, actions or observations",
    }  # fmt: skip
    return {"kind": "log", "meta": meta, "scene": scene, "frames": frames, "metrics": metrics}


def _json_number(value: Any) -> Any:
    value = value.item() if hasattr(value, "item") else value
    if isinstance(value, bool):
        return value
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return round(value, 4) if isinstance(value, float) else value
