"""Message classes for the part of the Waymo Open Motion ``Scenario`` protocol buffer replay reads.

The descriptors are built here in code from the published field numbers (wire-format facts: names,
numbers and types), in a private descriptor pool, so neither TensorFlow nor the Waymo package nor
``protoc`` is needed. Fields not listed (prediction targets, lidar, camera tokens) are kept by
protobuf as unknown fields and ignored. Enumerations are read as
plain integers, which is the same on the wire.
"""

from __future__ import annotations

from functools import lru_cache

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

PACKAGE = "smarts_replay.womd"

_T = descriptor_pb2.FieldDescriptorProto
DOUBLE, FLOAT, INT32, INT64, BOOL, STRING, MESSAGE = (
    _T.TYPE_DOUBLE, _T.TYPE_FLOAT, _T.TYPE_INT32, _T.TYPE_INT64, _T.TYPE_BOOL, _T.TYPE_STRING, _T.TYPE_MESSAGE,
)  # fmt: skip
ONE, MANY = _T.LABEL_OPTIONAL, _T.LABEL_REPEATED

# message name -> [(field name, number, type, label, message type name or None)]
MESSAGES: dict[str, list[tuple[str, int, int, int, str | None]]] = {
    "MapPoint": [("x", 1, DOUBLE, ONE, None), ("y", 2, DOUBLE, ONE, None), ("z", 3, DOUBLE, ONE, None)],
    "ObjectState": [
        ("center_x", 2, DOUBLE, ONE, None), ("center_y", 3, DOUBLE, ONE, None), ("center_z", 4, DOUBLE, ONE, None),
        ("length", 5, FLOAT, ONE, None), ("width", 6, FLOAT, ONE, None), ("height", 7, FLOAT, ONE, None),
        ("heading", 8, FLOAT, ONE, None), ("velocity_x", 9, FLOAT, ONE, None), ("velocity_y", 10, FLOAT, ONE, None),
        ("valid", 11, BOOL, ONE, None),
    ],
    "Track": [("id", 1, INT32, ONE, None), ("object_type", 2, INT32, ONE, None), ("states", 3, MESSAGE, MANY, "ObjectState")],
    "BoundarySegment": [
        ("lane_start_index", 1, INT32, ONE, None), ("lane_end_index", 2, INT32, ONE, None),
        ("boundary_feature_id", 3, INT64, ONE, None), ("boundary_type", 4, INT32, ONE, None),
    ],
    "LaneNeighbor": [
        ("feature_id", 1, INT64, ONE, None), ("self_start_index", 2, INT32, ONE, None),
        ("self_end_index", 3, INT32, ONE, None), ("neighbor_start_index", 4, INT32, ONE, None),
        ("neighbor_end_index", 5, INT32, ONE, None), ("boundaries", 6, MESSAGE, MANY, "BoundarySegment"),
    ],
    "LaneCenter": [
        ("speed_limit_mph", 1, DOUBLE, ONE, None), ("type", 2, INT32, ONE, None), ("interpolating", 3, BOOL, ONE, None),
        ("polyline", 8, MESSAGE, MANY, "MapPoint"), ("entry_lanes", 9, INT64, MANY, None),
        ("exit_lanes", 10, INT64, MANY, None), ("left_neighbors", 11, MESSAGE, MANY, "LaneNeighbor"),
        ("right_neighbors", 12, MESSAGE, MANY, "LaneNeighbor"), ("left_boundaries", 13, MESSAGE, MANY, "BoundarySegment"),
        ("right_boundaries", 14, MESSAGE, MANY, "BoundarySegment"),
    ],
    "RoadLine": [("type", 1, INT32, ONE, None), ("polyline", 2, MESSAGE, MANY, "MapPoint")],
    "RoadEdge": [("type", 1, INT32, ONE, None), ("polyline", 2, MESSAGE, MANY, "MapPoint")],
    "StopSign": [("lane", 1, INT64, MANY, None), ("position", 2, MESSAGE, ONE, "MapPoint")],
    "Crosswalk": [("polygon", 1, MESSAGE, MANY, "MapPoint")],
    "SpeedBump": [("polygon", 1, MESSAGE, MANY, "MapPoint")],
    "Driveway": [("polygon", 1, MESSAGE, MANY, "MapPoint")],
    "MapFeature": [
        ("id", 1, INT64, ONE, None), ("lane", 3, MESSAGE, ONE, "LaneCenter"), ("road_line", 4, MESSAGE, ONE, "RoadLine"),
        ("road_edge", 5, MESSAGE, ONE, "RoadEdge"), ("stop_sign", 7, MESSAGE, ONE, "StopSign"),
        ("crosswalk", 8, MESSAGE, ONE, "Crosswalk"), ("speed_bump", 9, MESSAGE, ONE, "SpeedBump"),
        ("driveway", 10, MESSAGE, ONE, "Driveway"),
    ],
    "TrafficSignalLaneState": [
        ("lane", 1, INT64, ONE, None), ("state", 2, INT32, ONE, None), ("stop_point", 3, MESSAGE, ONE, "MapPoint"),
    ],
    "DynamicMapState": [("lane_states", 1, MESSAGE, MANY, "TrafficSignalLaneState")],
    "Scenario": [
        ("timestamps_seconds", 1, DOUBLE, MANY, None), ("tracks", 2, MESSAGE, MANY, "Track"),
        ("objects_of_interest", 4, INT32, MANY, None), ("scenario_id", 5, STRING, ONE, None),
        ("sdc_track_index", 6, INT32, ONE, None), ("dynamic_map_states", 7, MESSAGE, MANY, "DynamicMapState"),
        ("map_features", 8, MESSAGE, MANY, "MapFeature"), ("current_time_index", 10, INT32, ONE, None),
    ],
}  # fmt: skip

OBJECT_VEHICLE, OBJECT_PEDESTRIAN, OBJECT_CYCLIST, OBJECT_OTHER = 1, 2, 3, 4
LANE_FREEWAY, LANE_SURFACE_STREET, LANE_BIKE = 1, 2, 3
"""Values of Track.ObjectType and LaneCenter.LaneType."""
SIGNAL_UNKNOWN, SIGNAL_ARROW_STOP, SIGNAL_ARROW_CAUTION, SIGNAL_ARROW_GO = 0, 1, 2, 3
SIGNAL_STOP, SIGNAL_CAUTION, SIGNAL_GO, SIGNAL_FLASHING_STOP, SIGNAL_FLASHING_CAUTION = 4, 5, 6, 7, 8
"""Values of TrafficSignalLaneState.State."""
SIGNAL_NAMES = ("unknown", "arrow_stop", "arrow_caution", "arrow_go", "stop", "caution", "go", "flashing_stop",
                "flashing_caution")  # fmt: skip
ROAD_LINE_KINDS = {1: "dashed_white", 2: "solid_white", 3: "solid_white", 4: "dashed_yellow", 5: "dashed_yellow",
                   6: "solid_yellow", 7: "double_yellow", 8: "double_yellow"}  # fmt: skip
"""RoadLine.RoadLineType -> the kind a picture draws (``recording.LINE_KINDS``)."""


@lru_cache(maxsize=1)
def message_classes() -> dict[str, type]:
    """Message name -> generated class (built once per process)."""
    file = descriptor_pb2.FileDescriptorProto(name="smarts_replay_womd.proto", package=PACKAGE, syntax="proto2")
    for name, fields in MESSAGES.items():
        message = file.message_type.add(name=name)
        for field_name, number, kind, label, type_name in fields:
            field = message.field.add(name=field_name, number=number, type=kind, label=label)
            if type_name is not None:
                field.type_name = f".{PACKAGE}.{type_name}"
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file)
    classes = {}
    for name in MESSAGES:
        descriptor = pool.FindMessageTypeByName(f"{PACKAGE}.{name}")
        classes[name] = message_factory.GetMessageClass(descriptor)
    return classes


def scenario_class() -> type:
    return message_classes()["Scenario"]
