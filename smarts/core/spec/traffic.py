"""The traffic part of a scenario: who else is on the road, for either traffic engine.

Plain dataclasses: the scenario reader (``smarts.scenario``) fills and checks them, the traffic
engines (``smarts.traffic``) read them.

The same spec drives SUMO (through libsumo) and the built-in vectorised model, so a scenario
switches engine with one field. Units: vehicles per hour for ``rate``, probability per second for
``probability``, seconds for times, metres and m/s elsewhere.

YAML shape (every field optional except where noted)::

    traffic:
      engine: builtin            # or sumo
      density: medium            # none | low | medium | high: generated flows between all
                                 # entry and exit roads, on top of the listed flows
      vehicle_types:
        calm: {base: passenger, max_speed: 25, accel: 2.0, tau: 1.5}
      flows:
        - {id: west_east, route: [west_in, east_out], rate: 600, vehicle_type: calm}
        - {id: to_north, origin: south_in, destination: north_out, probability: 0.1}
      trips:
        - {id: lead, origin: main_0, destination: main_2, depart: 0, depart_lane: 1,
           depart_pos: 40, depart_speed: 10}
      pedestrians:                # SUMO only; needs a map with sidewalks and crossings
        - {id: crossers, origin: south_in, destination: north_out, rate: 300}
"""

from __future__ import annotations

from dataclasses import dataclass, field

TRAFFIC_ENGINES = ("builtin", "sumo")
TRAFFIC_VEHICLE_BASES = ("passenger", "bus", "truck", "motorcycle")
"""What a ``VehicleTypeSpec.base`` may name."""
DENSITY_LEVELS = ("none", "low", "medium", "high")
DENSITY_RATES = {"none": 0.0, "low": 150.0, "medium": 400.0, "high": 900.0}
"""Vehicles per hour entering on each entry road at each density level."""
DEPART_LANES = ("best", "random", "free", "first")
"""Or a lane index (int). best: the lane with the most room that continues on the route."""
DEPART_SPEEDS = ("max", "desired", "random")
"""Or a speed in m/s (float)."""


@dataclass
class VehicleTypeSpec:
    """Driver and vehicle parameters, shared by both engines (SUMO vType semantics).

    Car following: ``accel``/``decel`` (comfortable), ``tau`` (desired time headway), ``min_gap``
    (standstill gap), ``speed_factor`` (x lane speed limit) with ``speed_dev`` spread. Lane
    changing: SUMO's ``lc_*`` weights; the built-in MOBIL model reads ``politeness`` and
    ``lc_threshold``. ``sigma`` is SUMO's driver imperfection (the built-in model ignores it).
    """

    id: str
    base: str = "passenger"  # passenger | bus | truck | motorcycle: dimensions and defaults
    length: float | None = None
    width: float | None = None
    height: float | None = None
    max_speed: float = 55.0
    accel: float = 2.6
    decel: float = 4.5
    emergency_decel: float = 9.0
    tau: float = 1.0
    min_gap: float = 2.5
    sigma: float = 0.5
    speed_factor: float = 1.0
    speed_dev: float = 0.1
    lc_strategic: float = 1.0
    lc_cooperative: float = 1.0
    lc_speed_gain: float = 1.0
    lc_keep_right: float = 1.0
    politeness: float = 0.3
    lc_threshold: float = 0.2  # m/s^2 of acceleration advantage a lane change must bring


DEFAULT_VEHICLE_TYPES: dict[str, VehicleTypeSpec] = {
    "car": VehicleTypeSpec("car"),
    "bus": VehicleTypeSpec("bus", base="bus", max_speed=27.0, accel=1.2, decel=4.0, tau=1.5),
    "truck": VehicleTypeSpec("truck", base="truck", max_speed=25.0, accel=1.3, decel=4.0, tau=1.5),
    "motorcycle": VehicleTypeSpec("motorcycle", base="motorcycle", accel=4.0, decel=7.0),
}
"""Types every scenario may name without declaring them."""


@dataclass
class FlowSpec:
    """Repeated departures: ``rate`` vehicles per hour (evenly spaced) or, instead, a departure
    ``probability`` each second. The path is ``route`` (consecutive roads, or just some roads
    the route passes in order) or ``origin`` and ``destination`` roads."""

    id: str
    route: list[str] | None = None
    origin: str | None = None
    destination: str | None = None
    rate: float | None = None
    probability: float | None = None
    begin: float = 0.0
    end: float = 3600.0
    vehicle_type: str = "car"
    depart_lane: str | int = "best"
    depart_speed: str | float = "desired"
    depart_pos: float = 0.0  # metres along the first road's lane

    @property
    def roads(self) -> list[str]:
        """The roads the vehicle must pass, in order (at least origin and destination)."""
        return list(self.route) if self.route else [self.origin, self.destination]


@dataclass
class TripSpec:
    """One vehicle departing at ``depart`` seconds; its id in the vehicle table is ``id``."""

    id: str
    route: list[str] | None = None
    origin: str | None = None
    destination: str | None = None
    depart: float = 0.0
    vehicle_type: str = "car"
    depart_lane: str | int = "best"
    depart_speed: str | float = "desired"
    depart_pos: float = 0.0

    @property
    def roads(self) -> list[str]:
        return list(self.route) if self.route else [self.origin, self.destination]


@dataclass
class PedestrianFlowSpec:
    """People walking from ``origin`` to ``destination`` road (on their sidewalks, through the
    crossings), SUMO engine only."""

    id: str
    origin: str
    destination: str
    rate: float | None = None
    probability: float | None = None
    begin: float = 0.0
    end: float = 3600.0
    speed: float = 1.3


@dataclass
class TrafficSpec:
    engine: str = "builtin"
    density: str = "none"
    vehicle_types: dict[str, VehicleTypeSpec] = field(default_factory=dict)
    flows: list[FlowSpec] = field(default_factory=list)
    trips: list[TripSpec] = field(default_factory=list)
    pedestrians: list[PedestrianFlowSpec] = field(default_factory=list)

    def vehicle_type(self, name: str) -> VehicleTypeSpec:
        """A declared type, or one of ``DEFAULT_VEHICLE_TYPES``."""
        if name in self.vehicle_types:
            return self.vehicle_types[name]
        return DEFAULT_VEHICLE_TYPES[name]
