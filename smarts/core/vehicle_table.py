"""The vehicle table: every road user's state as fixed-capacity arrays.

Rows are stable: a vehicle keeps its row from entry to removal, so providers, sensors and agents can
hold row indices across steps. Free rows are reused only after removal. No Python object exists per
vehicle; a step touches these arrays with vectorised operations only.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from smarts.core.geometry import box_corners
from smarts.core.vehicle_types import VEHICLE_DIMENSIONS, VehicleType


class Role(IntEnum):
    """Who a row belongs to, as seen by observations and metrics."""

    NONE = 0
    AGENT = 1  # driven by a learning agent through an action space
    SOCIAL_AGENT = 2  # driven by a non-learning policy stepped by the simulator
    TRAFFIC = 3  # driven by a traffic engine (SUMO or the built-in model)
    REPLAY = 4  # replayed from a dataset
    PEDESTRIAN = 5


NO_OWNER = -1


class VehicleTable:
    """Struct-of-arrays state of all vehicles with an id <-> row map.

    Kinematic columns are float64 (positions of a few km need the precision); ``lane``, ``s``, ``t``
    and ``lane_heading`` are written by the simulation after every step from the map projection.
    """

    FLOAT_COLUMNS: tuple[str, ...] = (
        "x",
        "y",
        "heading",
        "speed",
        "accel",  # longitudinal acceleration, m/s^2
        "jerk",  # longitudinal jerk, m/s^3
        "lat_accel",  # lateral acceleration (speed * yaw rate), m/s^2
        "yaw_rate",
        "steering",  # front wheel angle, rad (physics vehicles; 0 otherwise)
        "length",
        "width",
        "height",
        "s",
        "t",
        "lane_heading",
        "lane_distance",  # |distance| from the nearest lane centre line
    )

    def __init__(self, capacity: int = 256):
        if capacity <= 0:
            raise ValueError(f"vehicle table capacity must be positive, got {capacity}")
        self.capacity = capacity
        # One [columns, capacity] block: each column is a contiguous view (struct of arrays), and
        # ``data[:, rows]`` gathers every column of some rows in a single call.
        self.data = np.zeros((len(self.FLOAT_COLUMNS), capacity), dtype=np.float64)
        for i, name in enumerate(self.FLOAT_COLUMNS):
            setattr(self, name, self.data[i])
        self.lane = np.full(capacity, -1, dtype=np.int32)
        self.role = np.zeros(capacity, dtype=np.int8)
        self.vtype = np.zeros(capacity, dtype=np.int8)
        self.owner = np.full(capacity, NO_OWNER, dtype=np.int16)
        self.alive = np.zeros(capacity, dtype=bool)
        self.ids: list[str | None] = [None] * capacity
        self.row_of: dict[str, int] = {}
        # A number per vehicle added, never reused: a row with the serial it had still holds the
        # same vehicle (so per-agent caches of rows can be checked without looking ids up).
        self.serial = np.zeros(capacity, dtype=np.int64)
        self.serial_counter = np.zeros(1, dtype=np.int64)  # shared with block views of this table

    # ------------------------------------------------------------------ rows
    @property
    def alive_rows(self) -> np.ndarray:
        return np.flatnonzero(self.alive)

    def __len__(self) -> int:
        return len(self.row_of)

    def add(
        self,
        vehicle_id: str,
        *,
        owner: int,
        role: Role,
        x: float,
        y: float,
        heading: float,
        speed: float = 0.0,
        vtype: VehicleType = VehicleType.PASSENGER,
        length: float | None = None,
        width: float | None = None,
        height: float | None = None,
    ) -> int:
        """Insert a vehicle into the lowest free row and return the row."""
        if vehicle_id in self.row_of:
            raise ValueError(f"vehicle id {vehicle_id!r} is already in the table")
        free = np.flatnonzero(~self.alive)
        if free.size == 0:
            raise RuntimeError(
                f"vehicle table is full (capacity {self.capacity}); raise the scenario's 'vehicle_capacity'"
            )
        row = int(free[0])
        dl, dw, dh, _ = VEHICLE_DIMENSIONS[VehicleType(vtype)]
        self.data[:, row] = 0.0
        self.x[row], self.y[row], self.heading[row], self.speed[row] = x, y, heading, speed
        self.length[row] = dl if length is None else length
        self.width[row] = dw if width is None else width
        self.height[row] = dh if height is None else height
        self.lane[row] = -1
        self.role[row] = int(role)
        self.vtype[row] = int(vtype)
        self.owner[row] = owner
        self.alive[row] = True
        self.ids[row] = vehicle_id
        self.row_of[vehicle_id] = row
        self.serial_counter[0] += 1
        self.serial[row] = self.serial_counter[0]
        return row

    def remove(self, rows: np.ndarray | list[int] | int) -> None:
        for row in np.atleast_1d(np.asarray(rows, dtype=np.int64)):
            vid = self.ids[row]
            if vid is not None:
                del self.row_of[vid]
            self.ids[row] = None
            self.alive[row] = False
            self.owner[row] = NO_OWNER
            self.role[row] = int(Role.NONE)

    def transfer(self, rows: np.ndarray | list[int], owner: int, role: Role | None = None) -> None:
        """Hand rows to another provider; the state stays where it is (no copies)."""
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size and not self.alive[rows].all():
            dead = [int(r) for r in rows[~self.alive[rows]]]
            raise ValueError(f"cannot transfer rows {dead}: they hold no vehicle")
        self.owner[rows] = owner
        if role is not None:
            self.role[rows] = int(role)

    def rows_owned_by(self, owner: int) -> np.ndarray:
        return np.flatnonzero(self.alive & (self.owner == owner))

    def clear(self) -> None:
        self.remove(np.flatnonzero(self.alive))

    # ------------------------------------------------------------------ geometry
    def corners(self, rows: np.ndarray) -> np.ndarray:
        """Box corners float64[n, 4, 2] (front-left, front-right, rear-right, rear-left)."""
        d = self.data[_BOX_COLUMNS][:, rows]
        return box_corners(d[0], d[1], d[2], d[3], d[4])


COLUMN = {name: i for i, name in enumerate(VehicleTable.FLOAT_COLUMNS)}
"""Row of each float column in ``VehicleTable.data``."""
_BOX_COLUMNS = [COLUMN[c] for c in ("x", "y", "heading", "length", "width")]
