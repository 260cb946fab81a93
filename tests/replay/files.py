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


PORTAL_HEADER = [
    "Vehicle_ID", "Frame_ID", "Total_Frames", "Global_Time", "Local_X", "Local_Y", "Global_X", "Global_Y",
    "v_length", "v_Width", "v_Class", "v_Vel", "v_Acc", "Lane_ID", "O_Zone", "D_Zone", "Int_ID", "Section_ID",
    "Direction", "Movement", "Preceding", "Following", "Space_Headway", "Time_Headway", "Location",
]  # fmt: skip
"""The data portal's CSV header (every site in one file): ``v_length`` in lower case, the arterial
sites' zone/intersection/section/direction/movement columns (empty for the freeways) and
``Location``."""


def write_ngsim_portal(path: Path, sites: dict[str, dict[str, dict]], lower: bool = False) -> Path:
    """The portal's combined CSV: each site's vehicles (same ids and frames in every site), its rows
    interleaved as the portal serves them; ``lower``: every column name in lower case (the portal's
    API spelling)."""
    rows = []
    for site, vehicles in sites.items():
        for r in ngsim_rows(vehicles):
            rows.append([*r[:14], "", "", "", "", "", "", *r[14:], site])
    rows.sort(key=lambda r: (r[1], r[0]))  # by frame, as the portal's export is
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([h.lower() for h in PORTAL_HEADER] if lower else PORTAL_HEADER)
        w.writerows(rows)
    return path


def write_ngsim_txt(path: Path, vehicles: dict[str, dict]) -> Path:
    """The original trajectory .txt: no header, 18 blank-separated right-aligned columns."""
    widths = (5, 6, 5, 14, 9, 10, 13, 13, 6, 6, 2, 7, 7, 3, 5, 5, 8, 8)
    with open(path, "w") as f:
        for row in ngsim_rows(vehicles):
            f.write(" ".join(str(v).rjust(w) for v, w in zip(row, widths)) + "\n")
    return path


def slow_car(frames: int = 300, seed: int = 0, jitter: float = 0.15) -> tuple[dict, np.ndarray]:
    """A car in a queue along +x (lane 0): stop-and-go between standing and 2 m/s, positions jittered
    by ``jitter`` m per frame as NGSIM's are. Returns the vehicle and its true centre x."""
    t = np.arange(frames) * 0.1
    speed = np.clip(1.2 * np.sin(t / 3.0) + 0.8, 0.0, 2.0)  # stands for a while each cycle
    x = 20.0 + np.cumsum(speed) * 0.1
    rng = np.random.default_rng(seed)
    v = {"first": 1000, "x": x + rng.normal(0.0, jitter, frames), "y": LANE0_Y + rng.normal(0.0, jitter, frames),
         "length": 4.5, "width": 1.8, "cls": 2}  # fmt: skip
    return v, x


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


def av2_map_with_crossings(drivable_as_list: bool = False) -> dict:
    """``av2_map`` with a pedestrian crossing across both lanes at x 150, a bike lane beside the
    right lane and (``drivable_as_list``) its drivable areas written as a list."""
    data = av2_map()
    bike = av2_lane(901, 0.0, 200.0, -1.5, [])
    bike["right_lane_boundary"] = av2_boundary(0.0, 200.0, -1.5)
    bike["left_lane_boundary"] = av2_boundary(0.0, 200.0, 0.0)
    bike["lane_type"] = "BIKE"
    data["lane_segments"]["901"] = bike
    data["pedestrian_crossings"] = {"55": {
        "id": 55,
        "edge1": [{"x": 148.0, "y": -2.0, "z": 0.0}, {"x": 148.0, "y": 9.0, "z": 0.0}],
        "edge2": [{"x": 152.0, "y": -2.0, "z": 0.0}, {"x": 152.0, "y": 9.0, "z": 0.0}],
    }}  # fmt: skip
    if drivable_as_list:
        data["drivable_areas"] = list(data["drivable_areas"].values())
    return data


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
            f.lane.right_boundaries.add(
                lane_start_index=0, lane_end_index=10, boundary_feature_id=3001, boundary_type=0
            )
            f.lane.left_boundaries.add(lane_start_index=0, lane_end_index=10, boundary_feature_id=3002, boundary_type=1)
        else:
            f.lane.right_boundaries.add(
                lane_start_index=0, lane_end_index=10, boundary_feature_id=3002, boundary_type=1
            )
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


JUNCTION_ID = "7a6b5c4d3e2f1a0b"


def waymo_junction(scenario_id: str = JUNCTION_ID, jitter: bool = True, pedestrian_at=None):
    """A signalled junction as the motion dataset records one. Eastbound approach lane 101 (y = 0, x 0
    to 200) with a left-turn pocket 102 beside its last 40 m only (a partial neighbour: 101's points
    16..20 beside 102's 0..4); junction lanes 201 (straight on to 301), 202 (left, to the northbound
    401) and 203 (straight on from the pocket, which also turns left, to 302); exit road 301/302 (x 230 to 330) with a
    crosswalk across it at x 240, a speed bump at x 300 and a bike lane beside 401.

    Tracks: the self-driving car 1 drives 101 -> 201 -> 301 at 15 m/s from x 120 for all 91 frames;
    vehicle 2 waits in the pocket; cyclist 3 rides the exit road; pedestrian 4 walks along the
    crosswalk; object 5 is of type other. Signals: 201 stop (red) for frames 0..49, then go; 202
    arrow stop; 203 go. ``jitter``: timestamps 0.09999 s apart (the last at 8.9991 s, as recorded).
    ``pedestrian_at``: (x, y) where an extra pedestrian 6 stands from frame 0."""
    from smarts.replay.waymo_proto import message_classes

    c = message_classes()
    msg = c["Scenario"](scenario_id=scenario_id, current_time_index=10, sdc_track_index=0)
    msg.timestamps_seconds.extend([(0.09999 if jitter else 0.1) * k for k in range(91)])

    def track(track_id, kind, xy_at, length=4.8, width=2.0, valid=lambda k: True, heading=0.0):
        t = msg.tracks.add(id=track_id, object_type=kind)
        for k in range(91):
            x, y = xy_at(k)
            x1, y1 = xy_at(min(k + 1, 90))
            x0, y0 = xy_at(max(k - 1, 0))
            vx, vy = (
                (x1 - x0) / (0.1 * (min(k + 1, 90) - max(k - 1, 0))),
                (y1 - y0) / (0.1 * (min(k + 1, 90) - max(k - 1, 0))),
            )
            h = float(np.arctan2(vy, vx)) if np.hypot(vx, vy) > 0.1 else heading
            t.states.add(center_x=x, center_y=y, center_z=0.5, length=length + 0.02 * (k % 3), width=width,
                         height=1.6, heading=h, velocity_x=vx, velocity_y=vy, valid=bool(valid(k)))  # fmt: skip

    track(1, 1, lambda k: (120.0 + 1.5 * k, 0.0))
    track(2, 1, lambda k: (190.0, 3.7), heading=0.0)
    track(3, 3, lambda k: (235.0 + 0.5 * k, -1.2), length=1.8, width=0.7)
    track(4, 2, lambda k: (240.0, -3.0 + 0.1 * k), length=0.5, width=0.5, heading=np.pi / 2)
    track(5, 4, lambda k: (260.0, 8.0), length=1.0, width=1.0)
    if pedestrian_at is not None:
        track(6, 2, lambda k: pedestrian_at, length=0.5, width=0.5)

    def lane(feature_id, points, exits, interpolating=False, kind=2, left=(), right=()):
        f = msg.map_features.add(id=feature_id)
        f.lane.speed_limit_mph = 30.0
        f.lane.type = kind
        f.lane.interpolating = interpolating
        for x, y in points:
            f.lane.polyline.add(x=float(x), y=float(y), z=0.0)
        f.lane.exit_lanes.extend(exits)
        for side, spans in ((f.lane.left_neighbors, left), (f.lane.right_neighbors, right)):
            for other, s0, s1, n0, n1 in spans:
                side.add(feature_id=other, self_start_index=s0, self_end_index=s1, neighbor_start_index=n0,
                         neighbor_end_index=n1)  # fmt: skip

    def line(x0, x1, y, n):
        return [(x, y) for x in np.linspace(x0, x1, n)]

    lane(101, line(0.0, 200.0, 0.0, 21), [201], left=[(102, 16, 20, 0, 4)])
    lane(102, line(160.0, 200.0, 3.7, 5), [202, 203], right=[(101, 0, 4, 16, 20)])
    lane(201, line(200.0, 230.0, 0.0, 7), [301], interpolating=True)
    arc = [(200.0 + 18.0 * np.sin(a), 3.7 + 18.0 * (1 - np.cos(a))) for a in np.linspace(0.0, np.pi / 2, 10)]
    lane(202, arc, [401], interpolating=True)
    lane(203, line(200.0, 230.0, 3.7, 7), [302], interpolating=True)
    lane(301, line(230.0, 330.0, 0.0, 11), [], left=[(302, 0, 10, 0, 10)])
    lane(302, line(230.0, 330.0, 3.7, 11), [], right=[(301, 0, 10, 0, 10)])
    lane(401, [(218.0, 21.7 + 10.0 * k) for k in range(9)], [])
    lane(501, [(221.0, 21.7 + 10.0 * k) for k in range(9)], [], kind=3)  # a bike lane beside 401
    for line_id, y, kind in ((601, -1.85, "edge"), (602, 1.85, 1), (603, 5.55, "edge")):
        f = msg.map_features.add(id=line_id)
        target = f.road_edge if kind == "edge" else f.road_line
        target.type = 1
        for x in (0.0, 200.0):
            target.polyline.add(x=x, y=y, z=0.0)
    cross = msg.map_features.add(id=701)
    for x, y in ((238.0, -2.0), (242.0, -2.0), (242.0, 5.7), (238.0, 5.7)):
        cross.crosswalk.polygon.add(x=x, y=y, z=0.0)
    bump = msg.map_features.add(id=702)
    for x, y in ((300.0, -1.8), (300.6, -1.8), (300.6, 5.5), (300.0, 5.5)):
        bump.speed_bump.polygon.add(x=x, y=y, z=0.0)
    for k in range(91):
        state = msg.dynamic_map_states.add()
        for lane_id, code, stop in ((201, 4 if k < 50 else 6, (200.0, 0.0)), (202, 1, (200.0, 3.7)),
                                    (203, 6, (200.0, 3.7))):  # fmt: skip
            s = state.lane_states.add(lane=lane_id, state=code)
            s.stop_point.x, s.stop_point.y = stop
    return msg


def write_waymo(path: Path, scenarios=None) -> Path:
    from smarts.replay.tfrecord import write_records

    write_records(path, [m.SerializeToString() for m in (scenarios or [waymo_scenario()])])
    return path
