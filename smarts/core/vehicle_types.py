"""Kinds of road users and their typical sizes: plain definitions the scenario spec and the vehicle
table share (kept apart from the table, whose imports are the simulator's, so that reading a
config does not load the compiled kernels)."""

from __future__ import annotations

from enum import IntEnum


class VehicleType(IntEnum):
    PASSENGER = 0
    BUS = 1
    TRUCK = 2
    MOTORCYCLE = 3
    PEDESTRIAN = 4
    BICYCLE = 5  # a cyclist (replayed from datasets that record them)


# Typical box size (length, width, height) in metres and mass in kg per vehicle type; scenarios may
# override each value per agent.
VEHICLE_DIMENSIONS: dict[VehicleType, tuple[float, float, float, float]] = {
    VehicleType.PASSENGER: (4.6, 1.9, 1.5, 1500.0),
    VehicleType.BUS: (12.0, 2.55, 3.2, 12000.0),
    VehicleType.TRUCK: (10.0, 2.5, 3.6, 10000.0),
    VehicleType.MOTORCYCLE: (2.2, 0.8, 1.4, 250.0),
    VehicleType.PEDESTRIAN: (0.5, 0.5, 1.7, 75.0),
    VehicleType.BICYCLE: (1.8, 0.7, 1.7, 90.0),
}
