"""Small recordings written in the datasets' real formats, for the replay tests (no downloads)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

FEET = 0.3048
NGSIM_HEADER = [
    "Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y", "Global_X", "Global_Y",
    "v_Length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID", "Preceding", "Following", "Space_Hdwy",
    "Time_Hdwy",
]  # fmt: skip
GLOBAL_SHIFT = (6042000.0, 2133000.0)
"""feet added to Local_X, Local_Y to make Global_X, Global_Y (a state-plane-like origin)."""


def ngsim_rows(vehicles: dict[str, dict]) -> list[list]:
    """Rows of an NGSIM CSV for vehicles given in the map frame (metres, box centres).

    Each vehicle: ``first`` (frame id), ``x``/``y`` (arrays of box centres, one per frame, driving
    along +x), ``length``, ``width`` (m), ``cls`` (v_Class). The file's Local_Y is the map's x and
    its Local_X is minus the map's y (so read with swap_xy and flip_y), both in feet, at the
    vehicle's front edge."""
    rows = []
    for vid, v in vehicles.items():
        x, y = np.asarray(v["x"], float), np.asarray(v["y"], float)
        front_x = x + v["length"] / 2  # heading is +x in these tracks
        n = len(x)
        speed = np.gradient(x) / 0.1 if n > 1 else np.zeros(1)
        for k in range(n):
            frame = v["first"] + k
            local_x, local_y = -y[k] / FEET, front_x[k] / FEET
            rows.append([
                vid, frame, n, 1113433135300 + frame * 100, f"{local_x:.4f}", f"{local_y:.4f}",
                f"{local_x + GLOBAL_SHIFT[0]:.4f}", f"{local_y + GLOBAL_SHIFT[1]:.4f}",
                f"{v['length'] / FEET:.4f}", f"{v['width'] / FEET:.4f}", v.get("cls", 2),
                f"{speed[k] / FEET:.3f}", "0.00", 1, 0, 0, "0.00", "0.00",
            ])  # fmt: skip
    return rows


def write_ngsim(path: Path, vehicles: dict[str, dict], header: list[str] | None = None) -> Path:
    header = header or NGSIM_HEADER
    keep = [NGSIM_HEADER.index(h) for h in header]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in ngsim_rows(vehicles):
            w.writerow([row[i] for i in keep])
    return path


def straight(first: int, frames: int, x0: float, speed: float, y: float, length=4.5, width=1.8, cls=2) -> dict:
    """A vehicle driving along +x at constant speed from ``x0`` for ``frames`` frames."""
    x = x0 + speed * 0.1 * np.arange(frames)
    return {"first": first, "x": x, "y": np.full(frames, y), "length": length, "width": width, "cls": cls}


LANE0_Y = -4.8
LANE1_Y = -1.6
"""Centre lines of the two lanes of the built-in straight_2lane map (road 'main', +x, 300 m)."""


def three_vehicles() -> dict[str, dict]:
    """Vehicle 1 from frame 100 to 159, 2 from 110 to 189 (the other lane), 3 from 130 to 149."""
    return {
        "1": straight(100, 60, 20.0, 10.0, LANE0_Y),
        "2": straight(110, 80, 10.0, 12.0, LANE1_Y, length=12.0, width=2.5, cls=3),
        "3": straight(130, 20, 100.0, 8.0, LANE0_Y),
    }


# ---------------------------------------------------------------------------- Argoverse 2
AV2_ID = "0a1b2c3d-0000-4000-8000-000000000001"


def av2_boundary(x0: float, x1: float, y: float) -> list[dict]:
    return [{"x": float(x), "y": float(y), "z": 0.0} for x in np.linspace(x0, x1, 6)]


def av2_lane(lane_id: int, x0: float, x1: float, y_right: float, successors, left=None, right=None,
             intersection=False) -> dict:  # fmt: skip
    """A straight lane segment along +x, 3.5 m wide, its right boundary at ``y_right``."""
    return {
        "id": lane_id, "is_intersection": intersection, "lane_type": "VEHICLE",
        "left_lane_boundary": av2_boundary(x0, x1, y_right + 3.5),
        "right_lane_boundary": av2_boundary(x0, x1, y_right),
        "left_lane_mark_type": "DASHED_WHITE", "right_lane_mark_type": "SOLID_WHITE",
        "successors": list(successors), "predecessors": [],
        "left_neighbor_id": left, "right_neighbor_id": right,
    }  # fmt: skip


def av2_map() -> dict:
    """Two lanes along +x (right lane centre y = 1.75, left lane y = 5.25) in two 100 m segments."""
    lanes = [
        av2_lane(101, 0.0, 100.0, 0.0, [201], left=102),
        av2_lane(102, 0.0, 100.0, 3.5, [202], right=101),
        av2_lane(201, 100.0, 200.0, 0.0, [], left=202),
        av2_lane(202, 100.0, 200.0, 3.5, [], right=201),
    ]
    area = [{"x": x, "y": y, "z": 0.0} for x, y in ((0, 0), (200, 0), (200, 7), (0, 7))]
    return {
        "lane_segments": {str(lane["id"]): lane for lane in lanes},
        "drivable_areas": {"7": {"id": 7, "area_boundary": area}},
        "pedestrian_crossings": {},
    }


def av2_tracks() -> list[dict]:
    """Rows of the track table: 'AV' (ego) for all 110 steps, vehicle '11' from step 20 to 79 in the
    left lane, a bus '12' from 0 to 49, and a pedestrian (not replayed)."""
    rows = []

    def add(track, kind, steps, x0, vx, y, heading=0.0):
        for k, step in enumerate(steps):
            rows.append({"observed": step < 50, "track_id": track, "object_type": kind, "object_category": 2,
                         "timestep": step, "position_x": x0 + vx * 0.1 * k, "position_y": y, "heading": heading,
                         "velocity_x": vx, "velocity_y": 0.0, "scenario_id": AV2_ID,
                         "start_timestamp": 315966000000000000, "end_timestamp": 315966011000000000,
                         "num_timestamps": 110, "focal_track_id": "11", "city": "PIT"})  # fmt: skip

    add("AV", "vehicle", range(0, 110), 5.0, 10.0, 1.75)
    add("11", "vehicle", range(20, 80), 30.0, 12.0, 5.25)
    add("12", "bus", range(0, 50), 60.0, 5.0, 1.75)
    add("ped_1", "pedestrian", range(0, 110), 50.0, 0.0, -2.0, heading=1.57)
    return rows


def write_av2(folder: Path, tracks: list[dict] | None = None, map_data: dict | None = None) -> Path:
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    folder.mkdir(parents=True, exist_ok=True)
    rows = av2_tracks() if tracks is None else tracks
    table = pa.table({key: [r[key] for r in rows] for key in rows[0]})
    pq.write_table(table, folder / f"scenario_{AV2_ID}.parquet")
    (folder / f"log_map_archive_{AV2_ID}.json").write_text(json.dumps(av2_map() if map_data is None else map_data))
    return folder


# ---------------------------------------------------------------------------- Waymo Open Motion
WAYMO_ID = "5f1d2a3b4c5d6e7f"


def waymo_scenario(scenario_id: str = WAYMO_ID):
    """One Scenario of 91 frames (0.1 s): vehicle 7 in lane 1001 for all frames, vehicle 8 in the
    left lane 1002 valid from frame 10 to 60, a pedestrian, and vehicle 9 never valid. Lanes run
    along +x: 1001 (y = 0) and 1002 (y = 3.7) from 0 to 100 m, then 1003 and 1004 to 200 m."""
    from smarts.replay.waymo_proto import message_classes

    c = message_classes()
    msg = c["Scenario"](scenario_id=scenario_id, current_time_index=10, sdc_track_index=0)
    msg.timestamps_seconds.extend([0.1 * k for k in range(91)])

    def track(track_id, kind, valid, x0, vx, y, length=4.8, width=2.0):
        t = msg.tracks.add(id=track_id, object_type=kind)
        for k in range(91):
            t.states.add(center_x=x0 + vx * 0.1 * k, center_y=y, center_z=0.5, length=length, width=width, height=1.6,
                         heading=0.0, velocity_x=vx, velocity_y=0.0, valid=bool(valid(k)))  # fmt: skip

    track(7, 1, lambda k: True, 5.0, 10.0, 0.0)
    track(8, 1, lambda k: 10 <= k <= 60, 20.0, 8.0, 3.7, length=5.5, width=2.2)
    track(20, 2, lambda k: True, 50.0, 0.0, -4.0, length=0.6, width=0.6)
    track(9, 1, lambda k: False, 0.0, 0.0, 0.0)

    def lane(feature_id, x0, exits, left=None, right=None, mph=25.0):
        f = msg.map_features.add(id=feature_id)
        y = 0.0 if feature_id % 2 else 3.7
        f.lane.speed_limit_mph = mph
        f.lane.type = 2
        for x in np.linspace(x0, x0 + 100.0, 11):
            f.lane.polyline.add(x=float(x), y=y, z=0.0)
        f.lane.exit_lanes.extend(exits)
        if feature_id % 2:  # the right lanes know both boundaries, the left lanes only the right one
            f.lane.right_boundaries.add(lane_start_index=0, lane_end_index=10, boundary_feature_id=3001, boundary_type=0)
            f.lane.left_boundaries.add(lane_start_index=0, lane_end_index=10, boundary_feature_id=3002, boundary_type=1)
        else:
            f.lane.right_boundaries.add(lane_start_index=0, lane_end_index=10, boundary_feature_id=3002, boundary_type=1)
        for side, other in ((f.lane.left_neighbors, left), (f.lane.right_neighbors, right)):
            if other is not None:
                side.add(feature_id=other, self_start_index=0, self_end_index=10, neighbor_start_index=0,
                         neighbor_end_index=10)  # fmt: skip

    # road lines: the right edge of lanes 1001/1003 (y = -1.85) and the line between the lanes (y = 1.85)
    for line_id, y in ((3001, -1.85), (3002, 1.85)):
        f = msg.map_features.add(id=line_id)
        kind = f.road_edge if line_id == 3001 else f.road_line
        kind.type = 1
        for x in (0.0, 200.0):
            kind.polyline.add(x=x, y=y, z=0.0)

    lane(1001, 0.0, [1003], left=1002)
    lane(1002, 0.0, [1004], right=1001)
    lane(1003, 100.0, [], left=1004)
    lane(1004, 100.0, [], right=1003)
    stop = msg.map_features.add(id=2001)
    stop.stop_sign.lane.append(1003)
    stop.stop_sign.position.x, stop.stop_sign.position.y = 195.0, -2.0
    return msg


def write_waymo(path: Path, scenarios=None) -> Path:
    from smarts.replay.tfrecord import write_records

    write_records(path, [m.SerializeToString() for m in (scenarios or [waymo_scenario()])])
    return path
