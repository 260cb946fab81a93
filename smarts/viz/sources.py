"""Recorded episodes the viewer can open: episode recordings and benchmark episode logs.

A path is one file or a folder searched for ``*.npz`` below it (a benchmark run's ``logs``
folder, a folder of recordings, or both). A recording carries everything, the map included. A
benchmark log holds the agents' traces and, since version 2, its scene: the lead, the other road
users near the agents and the signal colours at every row (no actions or observations). Its map
comes from the benchmark suite it was run on: the suite file the log names (``info.suite_source``),
else the suite it names, else the suite named by the run's folder
(``runs/benchmark/<suite>/<run>/logs/...``), else the built-in suite of the log's task. Its
per-agent benchmark metrics are computed from the log itself.
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
from smarts.viz.capture import LEAD_ROLE
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
def _suite_entry(log_path: Path, scenario: str, task: str, info: dict | None = None):
    """The suite scenario a log was run on (see the module docstring for the search order)."""
    from smarts.benchmark.suites import load_suite, suite_names

    info = info or {}
    suites = []
    source = info.get("suite_source")
    if isinstance(source, str) and source and Path(source).is_file():
        suites.append(source)
    if isinstance(info.get("suite"), str):
        suites.append(info["suite"])
    for folder in log_path.parents:
        if folder.name == "logs":  # <suite>/logs or <suite>/<numbered run>/logs
            suites += [folder.parent.name, folder.parent.parent.name]
    suites += [task] + suite_names()
    tried = []
    for name in dict.fromkeys(suites):
        if name not in suite_names() and not (name.endswith((".yaml", ".yml")) and Path(name).is_file()):
            continue
        tried.append(name)
        try:
            entries = load_suite(name).scenarios
        except ValueError:
            continue
        for entry in entries:
            if entry.name == scenario:
                return entry
    raise LogError(f"scenario {scenario!r} is in none of the benchmark suites {tried}; cannot draw its map",
                   source=str(log_path), column="scenario")  # fmt: skip


def log_page_json(path: Path) -> dict[str, Any]:
    """A benchmark log as the page's episode: the suite scenario's map, the agents' traces as
    vehicles, the scene's lead (role ``lead``), other road users and signal colours, and each
    agent's benchmark metrics."""
    from smarts.benchmark.metrics.log import read_episode
    from smarts.benchmark.metrics.scores import agent_costs, score_episode
    from smarts.env.assembly import scenario_map

    log = read_episode(path)
    entry = _suite_entry(path, log.scenario, log.task, log.info)
    scene = map_scene(scenario_map(entry.spec))
    dims = {a.id: a.vehicle.dimensions() for a in entry.spec.agents}
    metrics: dict[str, Any] = {"episode": score_episode(log) if log.agents or log.failed else {}}
    metrics["agents"] = {a: c.as_dict() for a, c in agent_costs(log).items()} if log.agents else {}
    sc = log.scene
    times = {round(float(t), 6) for tr in log.agents.values() for t in tr.time}
    if sc is not None:
        times |= {round(float(t), 6) for t in sc.time}
    lead_ids = set(sc.leads.values()) if sc is not None else set()
    n_signals = len(scene["signals"])
    frames = []
    for k, t in enumerate(sorted(times)):
        frame: dict[str, Any] = {"step": k + 1, "t": t, "ids": [], "x": [], "y": [], "h": [], "speed": [],
                                 "length": [], "width": [], "role": [], "lane": [], "signals": [], "agents": {}}  # fmt: skip

        def add(vid: str, x: float, y: float, h: float, v: float, length: float, width: float, role: int) -> None:
            frame["ids"].append(vid)
            frame["x"].append(round(float(x), 2))
            frame["y"].append(round(float(y), 2))
            frame["h"].append(round(float(h), 3))
            frame["speed"].append(round(float(v), 2))
            frame["length"].append(round(float(length), 2))
            frame["width"].append(round(float(width), 2))
            frame["role"].append(int(role))
            frame["lane"].append(-1)

        if sc is not None:
            row = int(np.searchsorted(sc.time, t - 1e-6))
            if row < sc.num_rows and abs(sc.time[row] - t) < 1e-6:
                for j in range(int(sc.offsets[row]), int(sc.offsets[row + 1])):
                    i = int(sc.index[j])
                    vid = sc.ids[i]
                    role = LEAD_ROLE if vid in lead_ids else int(sc.role[i])
                    add(vid, sc.x[j], sc.y[j], sc.heading[j], sc.speed[j], sc.length[i], sc.width[i], role)
                if sc.signals.shape[1] == n_signals:  # the colours of the map's signals, in its order
                    frame["signals"] = sc.signals[row].astype(int).tolist()
        for agent, tr in log.agents.items():
            hit = np.flatnonzero(np.abs(tr.time - t) < 1e-6)
            if not hit.size:
                continue
            i = int(hit[0])
            d = dims.get(agent)
            add(agent, tr.x[i], tr.y[i], tr.heading[i], tr.speed[i], d.length if d else 4.6, d.width if d else 1.9,
                int(Role.AGENT))  # fmt: skip
            state = {c: _json_number(v[i]) for c, v in tr.columns().items()}
            events = [c for c in ("wrong_way", "partial_off_road", "off_road", "goal_reached", "red_light", "left_map")
                      if state.get(c)]  # fmt: skip
            frame["agents"][agent] = {"vehicle": agent, "action": None, "reward": None, "events": events,
                                      "neighbours": [], "waypoints": [], "log": state}  # fmt: skip
        frames.append(frame)
    note = ("a benchmark log holds the agents' traces, the lead, the road users near them and the signals; no "
            "actions or observations" if sc is not None else
            "a benchmark log of version 1 holds the agents' traces only: no traffic, actions or observations")  # fmt: skip
    meta = {
        "scenario": log.scenario, "task": log.task, "episode": log.episode, "seed": log.seed, "dt": log.dt,
        "agent_ids": log.agent_ids, "failure": log.failure, "info": log.info, "source": str(path), "note": note,
        "leads": dict(sc.leads) if sc is not None else {},
    }  # fmt: skip
    return {"kind": "log", "meta": meta, "scene": scene, "frames": frames, "metrics": metrics}


def _json_number(value: Any) -> Any:
    value = value.item() if hasattr(value, "item") else value
    if isinstance(value, bool):
        return value
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return round(value, 4) if isinstance(value, float) else value
