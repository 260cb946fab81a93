"""The golden cases: every built-in scenario, every scenario of both benchmark suites, the README's
scenario files, and a few scenarios that switch on what the others leave off (every sensor,
every action space and controller, dataset replay with take-over and reactive hand-over).

Each case is stepped for at most ``MAX_STEPS`` steps with ``SEEDS``, its learning agents driven by
``golden_actions``: a deterministic function of the observation (and, for world-frame targets, the
vehicle's pose), so every backend that gives the same observations gives the same actions.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

SEEDS = (0, 1, 2)
MAX_STEPS = 200

# ---------------------------------------------------------------------------- README files
README_SCENARIOS: dict[str, str] = {
    "readme_left_turn": """
name: my_left_turn
map: builtin:intersection_4way_1lane
step_length: 0.1
episode_steps: 400
seed: 42
vehicle_capacity: 256
agents:
  - id: agent_0
    action_space: relative_target_pose
    vehicle: {type: passenger}
    mission:
      start: {road: west_in, lane: 0, offset: 40, speed: 8}
      goal: {road: north_out, offset: 40}
events:
  terminate_on: [collision, off_road, reached_goal, max_steps]
  not_moving_seconds: 60
reward: {progress_weight: 1.0, collision_penalty: 10, off_road_penalty: 10, goal_bonus: 10}
""",
    "readme_sumo_pedestrians": """
map: builtin:intersection_4way_1lane_peds
agents:
  - mission: {start: {road: south_in, offset: 30, speed: 8}, goal: {road: north_out}}
traffic:
  engine: sumo
  density: medium
  vehicle_types:
    calm: {base: passenger, max_speed: 25, accel: 2.0, tau: 1.5}
  flows:
    - {id: west_east, route: [west_in, east_out], rate: 600, vehicle_type: calm}
    - {id: to_north, origin: south_in, destination: north_out, probability: 0.1}
  trips:
    - {id: lead, route: [east_in, west_out], depart: 0, depart_lane: 0, depart_pos: 40, depart_speed: 12}
  pedestrians:
    - {id: walkers, origin: south_in, destination: north_out, rate: 300}
""",
    "readme_all_sensors": """
map: builtin:intersection_4way_2lane
agents:
  - id: agent_0
    mission: {start: {road: south_in, lane: 1, offset: 30, speed: 8}, goal: {road: west_out}}
    interface:
      neighbours: {count: 8, radius: 50, extended: true}
      waypoints: {count: 20, spacing: 2}
      occlusion: {enabled: true, mode: hide, range: 50}
      rasters: {size: 64, resolution: 0.5, layers: [drivable, lanes, route, occupancy, occlusion], rgb: true}
      lidar: {rays: 64, range: 30, noise: 0.0}
      ego: {extended: true}
      signals: true
traffic: {engine: builtin, density: medium}
""",
    "readme_v2v": """
map: builtin:intersection_4way_1lane
agents:
  - {id: agent_0, mission: {start: {road: west_in, offset: 30, speed: 8}, goal: {road: east_out}}}
  - {id: agent_1, mission: {start: {road: south_in, offset: 30, speed: 8}, goal: {road: north_out}}}
traffic: {engine: builtin, density: medium}
comms:
  channels: 2
  range: 100
  latency: 1
  loss: 0.05
  bandwidth: 8
  message_size: 8
  max_messages: 8
  penetration: 0.5
  traffic_channel: -1
  channel_action: false
  agent_channels: {agent_1: 1}
""",
}

# ---------------------------------------------------------------------------- feature cases
_SIGNAL_JUNCTION = {
    "map": "builtin:intersection_4way_2lane_signal",
    "episode_steps": 300,
    "traffic": {"engine": "builtin", "density": "medium"},
}


def _agents(action_space: str, controller: str = "direct", interface: dict | None = None) -> list[dict]:
    extra = {"action_space": action_space, "controller": controller}
    if interface is not None:
        extra["interface"] = interface
    return [
        {"id": "agent_0", **extra,
         "mission": {"start": {"road": "south_in", "lane": 1, "offset": 30, "speed": 8}, "goal": {"road": "north_out", "offset": 30}}},
        {"id": "agent_1", **extra,
         "mission": {"start": {"road": "west_in", "lane": 0, "offset": 25, "speed": 6}, "goal": {"road": "east_out", "offset": 30}}},
    ]  # fmt: skip


FEATURE_SCENARIOS: dict[str, dict] = {
    "feature_occlusion_flag": {
        **_SIGNAL_JUNCTION,
        "agents": _agents(
            "relative_target_pose",
            interface={
                "neighbours": {"count": 6, "radius": 40, "extended": True},
                "occlusion": {"enabled": True, "mode": "flag", "range": 40},
                "lidar": {"rays": 32, "range": 25, "noise": 0.05},
                "rasters": {"size": 32, "resolution": 1.0, "layers": ["drivable", "occupancy", "occlusion"]},
                "ego": {"extended": True},
                "signals": True,
                "ahead": True,
            },
        ),
    },  # fmt: skip
    "feature_target_pose": {**_SIGNAL_JUNCTION, "agents": _agents("target_pose")},
    "feature_continuous": {**_SIGNAL_JUNCTION, "agents": _agents("continuous")},
    "feature_lane": {**_SIGNAL_JUNCTION, "agents": _agents("lane")},
    "feature_lane_relative": {**_SIGNAL_JUNCTION, "agents": _agents("relative_target_pose", "lane_relative")},
    "feature_mixed_spaces": {
        **_SIGNAL_JUNCTION,
        "agents": [_agents("continuous")[0], _agents("target_pose", "lane_relative")[1]],
    },
}

# ---------------------------------------------------------------------------- replay case
FEET = 0.3048
_NGSIM_HEADER = [
    "Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y", "Global_X", "Global_Y",
    "v_Length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID", "Preceding", "Following", "Space_Hdwy",
    "Time_Hdwy",
]  # fmt: skip


def write_ngsim(path: Path) -> Path:
    """Four vehicles on the two lanes of ``builtin:straight_2lane`` (road ``main`` along +x, lane
    centres at y = -4.8 and -1.6), in the published NGSIM layout (feet, front edge, Local_Y along
    the road), one changing speed so the replayed vehicles accelerate."""
    tracks = {
        "1": (100, 80, 30.0, 10.0, -4.8, 0.0),
        "2": (100, 90, 12.0, 12.0, -1.6, 0.0),
        "3": (115, 40, 80.0, 8.0, -4.8, 0.0),
        "4": (100, 100, 50.0, 6.0, -1.6, 0.05),
    }
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(_NGSIM_HEADER)
        for vid, (first, frames, x0, v0, y, accel) in tracks.items():
            t = 0.1 * np.arange(frames)
            x = x0 + v0 * t + 0.5 * accel * t * t * 10
            speed = v0 + accel * 10 * t
            for k in range(frames):
                frame = first + k
                local_x, local_y = -y / FEET, (x[k] + 2.25) / FEET
                w.writerow([
                    vid, frame, frames, 1113433135300 + frame * 100, f"{local_x:.4f}", f"{local_y:.4f}",
                    f"{local_x + 6042000.0:.4f}", f"{local_y + 2133000.0:.4f}", f"{4.5 / FEET:.4f}",
                    f"{1.8 / FEET:.4f}", 2, f"{speed[k] / FEET:.3f}", "0.00", 1, 0, 0, "0.00", "0.00",
                ])  # fmt: skip
    return path


REPLAY_SCENARIO = {
    "map": "builtin:straight_2lane",
    "episode_steps": 150,
    "replay": {
        "format": "ngsim", "path": "golden_ngsim.csv", "swap_xy": True, "flip_y": True,
        "take_over": {"ego": 2}, "reactive": "interaction",
    },
    "agents": [
        {"id": "ego"},
        {"id": "agent_1", "mission": {"start": {"road": "main", "lane": 0, "offset": 5, "speed": 9}, "goal": {"endless": True}}},
    ],
}  # fmt: skip


# ---------------------------------------------------------------------------- all cases
@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    load: Callable[[Path], object]  # work folder -> ScenarioSpec
    sumo: bool = False


def _from_yaml_text(name: str, text: str) -> Callable[[Path], object]:
    def load(work: Path):
        from smarts.scenario import load_scenario

        path = work / f"{name}.yaml"
        path.write_text(text)
        return load_scenario(path)

    return load


def _from_dict(name: str, data: dict, files: Callable[[Path], None] | None = None) -> Callable[[Path], object]:
    def load(work: Path):
        from smarts.scenario import load_scenario

        if files is not None:
            files(work)
        path = work / f"{name}.yaml"
        path.write_text(yaml.safe_dump(copy.deepcopy(data)))
        return load_scenario(path)

    return load


def _library(name: str) -> Callable[[Path], object]:
    def load(work: Path):
        from smarts.scenario import load_scenario

        return load_scenario(name)

    return load


def _suite(suite: str, name: str) -> Callable[[Path], object]:
    def load(work: Path):
        from smarts.benchmark.suites import load_suite

        return next(s.spec for s in load_suite(suite).scenarios if s.name == name)

    return load


def all_cases() -> list[Case]:
    from smarts.benchmark.suites import load_suite
    from smarts.scenario.library import list_scenarios as scenario_names

    cases = []
    for name in scenario_names():
        spec = _library(name)(Path("."))
        cases.append(Case(f"library/{name}", _library(name), _is_sumo(spec)))
    for suite in ("adaptive", "collaborative"):
        for entry in load_suite(suite).scenarios:
            cases.append(Case(f"{suite}/{entry.name}", _suite(suite, entry.name), _is_sumo(entry.spec)))
    for name, text in README_SCENARIOS.items():
        cases.append(Case(f"readme/{name}", _from_yaml_text(name, text), "engine: sumo" in text))
    for name, data in FEATURE_SCENARIOS.items():
        cases.append(Case(f"feature/{name}", _from_dict(name, data)))
    cases.append(Case("feature/replay_ngsim", _from_dict("replay_ngsim", REPLAY_SCENARIO,
                                                         lambda w: write_ngsim(w / "golden_ngsim.csv"))))  # fmt: skip
    return cases


def _is_sumo(spec) -> bool:
    return spec.traffic is not None and spec.traffic.engine == "sumo"


# ---------------------------------------------------------------------------- the driver
def golden_actions(
    obs: dict[str, np.ndarray],
    kinds: list[tuple[str, str]],
    poses: np.ndarray,
    local_index: np.ndarray,
    step: int,
    dt: float,
    message_size: int = 0,
) -> np.ndarray:
    """Actions of n agents: ``obs`` {key: [n, ...]}, ``kinds[i]`` (action space, controller),
    ``poses`` float64[n, 3] world x, y, heading, ``local_index`` the agent's index in its scenario,
    ``step`` the episode's step. Row ``i`` depends only on row ``i`` of the inputs, so any batch
    gives each agent the same action. Returns float32[n, width] (``width``: the widest action,
    plus ``message_size`` message floats after each agent's driving part)."""
    from agents.keep_lane import KeepLanePolicy

    n = len(kinds)
    keep = KeepLanePolicy(dt=dt).act(obs).astype(np.float64)  # [n, 3] dx, dy, dheading (ego frame)
    sway = 0.04 * np.sin(0.15 * step + 1.3 * local_index)
    ego = obs["ego"].astype(np.float64)
    wp = obs["waypoints"][:, 0, 2].astype(np.float64)  # the route point ~4 m ahead, ego frame
    out = np.zeros((n, 3 + message_size))
    for i, (space, controller) in enumerate(kinds):
        if controller == "lane_relative":
            change = (
                1.0 if (step + local_index[i]) % 60 == 30 else (-1.0 if (step + local_index[i]) % 60 == 50 else 0.0)
            )
            out[i, :2] = (7.0 + 2.0 * math.sin(0.05 * step + local_index[i]), change)
            width = 2
        elif space == "relative_target_pose":
            out[i, :3] = keep[i] + (0.0, sway[i], 0.5 * sway[i])
            width = 3
        elif space == "target_pose":
            x, y, h = poses[i]
            dx, dy, dh = keep[i] + (0.0, sway[i], 0.0)
            c, s = math.cos(h), math.sin(h)
            out[i, :3] = (x + c * dx - s * dy, y + s * dx + c * dy, h + dh)
            width = 3
        elif space == "continuous":
            speed = ego[i, 0]
            throttle = min(max(0.4 * (8.0 - speed), 0.0), 1.0)
            brake = min(max(0.3 * (speed - 10.0), 0.0), 1.0)
            steer = min(max(0.8 * math.atan2(wp[i, 1], max(wp[i, 0], 1.0)), -0.6), 0.6)
            out[i, :3] = (throttle, brake, steer)
            width = 3
        else:  # lane: target speed, lane change
            change = 1.0 if (step + local_index[i]) % 50 == 20 else 0.0
            out[i, :2] = (8.0 + local_index[i], change)
            width = 2
        if message_size:
            out[i, width : width + message_size] = np.sin(0.1 * step + np.arange(message_size) + local_index[i])
    return out.astype(np.float32)


def action_width(space: str, controller: str) -> int:
    return 2 if controller == "lane_relative" or space == "lane" else 3
