"""What the viewer shows of one step, taken from a running ``DrivingParallelEnv``.

A step is captured in two halves: the env's step listener copies the vehicle table and the signal
colours while agents that finished on this step still have their vehicles (``StepCapture.on_step``),
and the wrapper then adds what only ``step()`` returns (actions, rewards, events, observations).
Everything is copied as whole-array slices of the vehicle table (the id strings with one gather).

A frame is a dict of plain arrays and lists (``Frame``); ``frame_json`` turns it into the JSON the
page reads, and ``smarts.viz.recording`` stacks frames into an episode recording.
"""

from __future__ import annotations

from operator import itemgetter
from typing import Any

import numpy as np

from smarts.core.events import EVENT_NAMES

VEHICLE_COLUMNS = ("x", "y", "heading", "speed", "length", "width")
"""Columns of ``Frame["vehicle_state"]``."""
LEAD_ROLE = 6
"""The page's role of a vehicle an agent follows (a lead): the table's roles are 0-5; a lead keeps
whatever it is driven by (traffic, replay, ...) in the simulation, but a viewer must tell it
apart from the agent and from the rest of the traffic at a glance."""
ROLE_NAMES = ["none", "agent", "social_agent", "traffic", "replay", "pedestrian", "lead"]

FIELD_UNITS = {
    "dx": "m", "dy": "m", "dheading": "rad", "x": "m", "y": "m", "heading": "rad", "throttle": "0..1",
    "brake": "0..1", "steering": "-1..1, + left", "target_speed": "m/s", "speed": "m/s",
    "lane_change": "-1 right, +1 left",
}  # fmt: skip


def action_fields(spec: Any) -> dict[str, list[str]]:
    """Per learning agent of a scenario spec: the names of its action's fields with their units
    (``dx (m)``, ...), from its action space and controller, so the viewer can label an action
    instead of printing bare numbers."""
    from smarts.dynamics.action_spaces import ACTION_COMPONENTS, LANE_RELATIVE_COMPONENTS, ActionSpaceType

    out = {}
    for agent in getattr(spec, "agents", []):
        if getattr(agent, "is_social", False):
            continue
        try:
            names = (LANE_RELATIVE_COMPONENTS if agent.controller == "lane_relative"
                     else ACTION_COMPONENTS[ActionSpaceType(agent.action_space)])  # fmt: skip
        except (ValueError, KeyError):
            continue
        out[str(agent.id)] = [f"{n} ({FIELD_UNITS[n]})" if n in FIELD_UNITS else n for n in names]
    return out


Frame = dict[str, Any]


class StepCapture:
    """Builds frames of one env; ``env`` is a ``DrivingParallelEnv`` (or anything with its ``sim``,
    ``sensors`` and ``possible_agents``)."""

    def __init__(self, env: Any):
        self.env = env
        self.agent_ids: list[str] = list(env.possible_agents)
        sim = env.sim
        self._agents = np.array([sim.agent_index[a] for a in self.agent_ids], dtype=np.int64)
        self._columns = [sim.table.FLOAT_COLUMNS.index(c) for c in VEHICLE_COLUMNS]
        # The last column of a neighbour row is its visible fraction when occlusion is on.
        self._visible = np.array(
            [bool(env.sensors.interface(int(a)).occlusion.enabled) for a in self._agents], dtype=bool
        )
        self._pending: Frame | None = None

    # --------------------------------------------------------------------------- halves
    def on_step(self, sim: Any) -> None:
        """Step listener: the world state of the step just taken (before finished agents leave)."""
        self._pending = self.world(sim)

    def world(self, sim: Any) -> Frame:
        """Vehicles, signal colours and each agent's vehicle row, as copies."""
        table = sim.table
        rows = table.alive_rows
        ids = table.ids
        signals = getattr(sim, "signals", None)
        agent_rows = np.where(sim.agent_active[self._agents], sim.agent_row[self._agents], -1)
        roles = table.role[rows].copy()
        leads = [table.row_of.get(lead) for lead in getattr(sim, "lead_ids", []) if lead is not None]
        if leads:
            roles[np.isin(rows, [r for r in leads if r is not None])] = LEAD_ROLE
        return {
            "time": float(sim.time),
            "vehicle_ids": _ids_of(ids, rows),
            "vehicle_state": table.data[self._columns][:, rows].T.astype(np.float32),
            "vehicle_role": roles,
            "vehicle_lane": table.lane[rows].copy(),
            "signal_colour": (
                signals.colour.copy() if signals is not None and signals.has_signals else np.zeros(0, np.int8)
            ),
            "agent_vehicle": np.searchsorted(rows, agent_rows).astype(np.int64) * (agent_rows >= 0) - (agent_rows < 0),
            "agent_pose": np.where(
                (agent_rows >= 0)[:, None],
                np.stack([table.x[agent_rows], table.y[agent_rows], table.heading[agent_rows]], axis=1),
                np.nan,
            ),
        }

    def reset_frame(self, obs: dict) -> Frame:
        """The frame of the state ``reset`` returned (no actions or rewards yet)."""
        frame = self.world(self.env.sim)
        self._add_agents(frame, obs, {}, {}, {})
        return frame

    def step_frame(self, actions: dict, obs: dict, rewards: dict, infos: dict) -> Frame:
        """The frame of the step just returned; needs ``on_step`` to have run during it."""
        frame = self._pending if self._pending is not None else self.world(self.env.sim)
        self._pending = None
        self._add_agents(frame, obs, actions, rewards, infos)
        return frame

    # --------------------------------------------------------------------------- agents
    def _add_agents(self, frame: Frame, obs: dict, actions: dict, rewards: dict, infos: dict) -> None:
        pose = frame["agent_pose"]
        agent_data: dict[str, dict] = {}
        for k, agent in enumerate(self.agent_ids):
            if frame["agent_vehicle"][k] < 0:
                continue
            entry: dict[str, Any] = {
                "vehicle": frame["vehicle_ids"][int(frame["agent_vehicle"][k])],
                "action": None if agent not in actions else np.asarray(actions[agent], dtype=np.float32).ravel(),
                "reward": None if agent not in rewards else float(rewards[agent]),
                "events": list(infos.get(agent, {}).get("events", [])),
            }
            if agent in obs:
                entry.update(_observation_in_world(obs[agent], pose[k], bool(self._visible[k])))
            agent_data[agent] = entry
        frame["agents"] = agent_data


def _ids_of(ids: list, rows: np.ndarray) -> list:
    """The id strings of ``rows`` (one C-level gather, no Python loop over vehicles)."""
    if rows.size == 0:
        return []
    if rows.size == 1:
        return [ids[int(rows[0])]]
    return list(itemgetter(*rows.tolist())(ids))


def _observation_in_world(ob: dict, pose: np.ndarray, visible: bool) -> dict:
    """An agent's neighbours (x, y, visible fraction) and waypoint paths in the map frame."""
    x, y, heading = (float(v) for v in pose)
    c, s = np.cos(heading), np.sin(heading)
    out: dict[str, Any] = {}
    if "neighbours" in ob:
        nb = np.asarray(ob["neighbours"], dtype=np.float64)
        mask = np.asarray(ob.get("neighbour_mask", np.ones(len(nb))), dtype=bool)
        dx, dy = nb[mask, 0], nb[mask, 1]
        vis = nb[mask, -1] if visible else np.ones(int(mask.sum()))
        out["neighbours"] = np.stack([x + c * dx - s * dy, y + s * dx + c * dy, vis], axis=1).astype(np.float32)
    if "waypoints" in ob:
        wp = np.asarray(ob["waypoints"], dtype=np.float64)
        mask = np.asarray(ob.get("waypoint_mask", np.ones(wp.shape[:2])), dtype=bool)
        wx = x + c * wp[..., 0] - s * wp[..., 1]
        wy = y + s * wp[..., 0] + c * wp[..., 1]
        world = np.stack([wx, wy], axis=-1)
        world[~mask] = np.nan
        out["waypoints"] = world.astype(np.float32)
    return out


def _num(value: float, digits: int = 2) -> float | None:
    return None if value is None or not np.isfinite(value) else round(float(value), digits)


def _rounded(values: np.ndarray, digits: int = 2) -> list:
    """A nested list with NaN and infinities as None (JSON has neither), built in one pass."""
    arr = np.round(np.asarray(values, dtype=np.float64), digits)
    finite = np.isfinite(arr)
    if finite.all():
        return arr.tolist()
    return np.where(finite, arr, None).tolist()


def frame_json(frame: Frame, step: int) -> dict:
    """The page's frame: vehicles as parallel lists, signal colours, and per agent its vehicle,
    action, reward, events, neighbours and waypoints (map frame)."""
    state = np.round(np.asarray(frame["vehicle_state"], dtype=np.float64), 2)
    agents = {}
    for agent, entry in frame.get("agents", {}).items():
        agents[agent] = {
            "vehicle": str(entry["vehicle"]),
            "action": None if entry.get("action") is None else _rounded(entry["action"], 3),
            "reward": _num(entry.get("reward"), 4),
            "events": list(entry.get("events", [])),
            "neighbours": _rounded(entry["neighbours"]) if "neighbours" in entry else [],
            "waypoints": _rounded(entry["waypoints"]) if "waypoints" in entry else [],
        }
    return {
        "step": int(step),
        "t": round(float(frame["time"]), 4),
        "ids": [str(i) for i in frame["vehicle_ids"]],
        "x": state[:, 0].tolist(),
        "y": state[:, 1].tolist(),
        "h": np.round(state[:, 2], 3).tolist(),
        "speed": state[:, 3].tolist(),
        "length": state[:, 4].tolist(),
        "width": state[:, 5].tolist(),
        "role": np.asarray(frame["vehicle_role"]).astype(int).tolist(),
        "lane": np.asarray(frame["vehicle_lane"]).astype(int).tolist(),
        "signals": np.asarray(frame["signal_colour"]).astype(int).tolist(),
        "agents": agents,
    }


EVENTS = list(EVENT_NAMES)
