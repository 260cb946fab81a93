"""Small builders for V2V tests: vehicle tables with agents and traffic at given poses."""

from __future__ import annotations

import numpy as np

from smarts.core.vehicle_table import Role, VehicleTable


def table_with(
    poses: dict[str, tuple[float, float, float]], capacity: int = 64, traffic: tuple[str, ...] = ()
) -> tuple[VehicleTable, dict[str, int]]:
    """A table holding one vehicle per id at (x, y, heading); ids in ``traffic`` are traffic."""
    table = VehicleTable(capacity)
    rows = {}
    for vid, (x, y, h) in poses.items():
        role = Role.TRAFFIC if vid in traffic else Role.AGENT
        rows[vid] = table.add(vid, owner=1 if vid in traffic else 0, role=role, x=x, y=y, heading=h, speed=2.0)
    return table, rows


def rows_of(rows: dict[str, int], *ids: str) -> np.ndarray:
    return np.array([rows[i] for i in ids], dtype=np.int64)


def delivered_from(received, i: int) -> list[int]:
    """Sender rows of receiver i's messages, in delivery order."""
    return received.sender_row[i, received.mask[i]].tolist()
