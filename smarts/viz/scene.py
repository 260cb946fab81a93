"""The map as the page draws it: lane centre lines with their widths and attributes, lane links,
junction outlines and signal stop lines, as plain JSON-ready data.

Built once per map (every frame refers to lanes and signal connections by index), and stored
inside recordings so a recording can be viewed without the map file or netconvert.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smarts.maps import RoadMap

SCENE_VERSION = 1


def _round(values: np.ndarray, digits: int = 2) -> list:
    return np.round(np.asarray(values, dtype=np.float64), digits).tolist()


def map_scene(road_map: RoadMap) -> dict[str, Any]:
    """The drawable, clickable description of ``road_map``: per lane its id, road, index on the
    road, whether it lies in a junction, width, speed limit, length, centre polyline and the lanes
    it leads to and comes from; the junction outlines; and for each signal-controlled connection
    (in ``SignalState.connections`` order) its signal, incoming lane and stop position."""
    rm = road_map
    lanes = []
    for lane in range(rm.num_lanes):
        lanes.append(
            {
                "id": rm.lane_ids[lane],
                "road": rm.road_ids[int(rm.lane_road[lane])],
                "index": int(rm.lane_index[lane]),
                "internal": bool(rm.lane_internal[lane]),
                "width": round(float(rm.lane_width[lane]), 3),
                "speed_limit": round(float(rm.lane_speed_limit[lane]), 3),
                "length": round(float(rm.lane_length[lane]), 3),
                "points": _round(rm.lane_polyline(lane)),
                "successors": rm.successors(lane).astype(int).tolist(),
                "predecessors": rm.predecessors(lane).astype(int).tolist(),
            }
        )
    connections = np.flatnonzero(rm.conn_tls >= 0)
    signals = []
    for c in connections.tolist():
        from_lane = int(rm.conn_from[c])
        stop = rm.lane_polyline(from_lane)[-1]
        signals.append(
            {
                "tls": rm.tls_ids[int(rm.conn_tls[c])],
                "link": int(rm.conn_link[c]),
                "from_lane": from_lane,
                "via_lane": int(rm.conn_via[c]),
                "to_lane": int(rm.conn_to[c]),
                "stop": _round(stop),
            }
        )
    return {
        "version": SCENE_VERSION,
        "source": str(rm.source),
        "bounds": _round(rm.bounds),
        "lanes": lanes,
        "junctions": [_round(shape) for shape in rm.junction_shapes],
        "signals": signals,
    }
