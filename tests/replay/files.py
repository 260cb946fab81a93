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
