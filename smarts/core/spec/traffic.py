"""The traffic part of a scenario: who else is on the road, for either traffic engine.

Frozen, validated models: the scenario reader (``smarts.scenario``) reads a file's ``traffic:``
section into them, the traffic engines (``smarts.traffic``) read them. Checks that need the map
(roads, routes) are in ``smarts.scenario.map_check``.

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

from typing import Annotated, Any, Literal

from pydantic import Field, PlainValidator, model_validator

from smarts.core.schema import Schema, field_errors
from smarts.core.spec.base import MAX_SPEED, NonNegative, Positive, Spec, Text, Time

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
MAX_WALKING_SPEED = 10.0
"""m/s: the most a pedestrian flow's walking speed may be."""
MAX_FLOW_RATE = 10_000.0
"""Vehicles (or people) per hour of one flow: a departure every 0.36 s, more than four lanes
carry. Heavier traffic is several flows (SUMO refuses rates whose departures are closer than it
can time, with an error that names no field)."""


def _depart_lane(value: Any) -> str | int:
    if (isinstance(value, str) and value in DEPART_LANES) or (
        isinstance(value, int) and not isinstance(value, bool) and value >= 0
    ):
        return value
    raise ValueError(f"expected one of {', '.join(DEPART_LANES)} or a lane index (an integer >= 0)")


def _depart_speed(value: Any) -> str | float:
    if isinstance(value, str) and value in DEPART_SPEEDS:
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= MAX_SPEED:
        return float(value)
    raise ValueError(f"expected one of {', '.join(DEPART_SPEEDS)} or a speed in m/s from 0 to {MAX_SPEED:g}")


Rate = Annotated[float, Field(gt=0, le=MAX_FLOW_RATE, allow_inf_nan=False)]
"""Per hour, up to ``MAX_FLOW_RATE``."""
Probability = Annotated[float, Field(gt=0, le=1)]
DepartLane = Annotated[str | int, PlainValidator(_depart_lane, json_schema_input_type=str | int)]
DepartSpeed = Annotated[str | float, PlainValidator(_depart_speed, json_schema_input_type=str | float)]


class VehicleTypeSpec(Spec):
    """Driver and vehicle parameters, shared by both engines (SUMO vType semantics).

    Car following: ``accel``/``decel`` (comfortable), ``tau`` (desired time headway), ``min_gap``
    (standstill gap), ``speed_factor`` (x lane speed limit) with ``speed_dev`` spread. Lane
    changing: SUMO's ``lc_*`` weights; the built-in MOBIL model reads ``politeness`` and
    ``lc_threshold``. ``sigma`` is SUMO's driver imperfection (the built-in model ignores it).
    """

    id: str = Field(description="The type's name: its key in traffic.vehicle_types (filled in from the key).")
    base: Literal[TRAFFIC_VEHICLE_BASES] = Field(  # type: ignore[valid-type]
        "passenger", description="Dimensions and defaults of this kind of vehicle."
    )
    length: Positive | None = None
    width: Positive | None = None
    height: Positive | None = None
    max_speed: Annotated[float, Field(gt=0, le=MAX_SPEED, allow_inf_nan=False)] = Field(
        55.0, description=f"m/s, at most {MAX_SPEED:g}."
    )
    accel: Positive = 2.6
    decel: Positive = 4.5
    emergency_decel: Positive = 9.0
    tau: Positive = Field(1.0, description="Desired time headway (s).")
    min_gap: NonNegative = Field(2.5, description="Standstill gap (m).")
    sigma: Annotated[float, Field(ge=0, le=1)] = Field(0.5, description="SUMO's driver imperfection.")
    speed_factor: Positive = Field(1.0, description="x the lane speed limit.")
    speed_dev: NonNegative = 0.1
    lc_strategic: NonNegative = 1.0
    lc_cooperative: NonNegative = 1.0
    lc_speed_gain: NonNegative = 1.0
    lc_keep_right: NonNegative = 1.0
    politeness: NonNegative = Field(0.3, description="MOBIL politeness (built-in engine).")
    lc_threshold: NonNegative = Field(0.2, description="m/s^2 of acceleration advantage a lane change must bring.")


DEFAULT_VEHICLE_TYPES: dict[str, VehicleTypeSpec] = {
    "car": VehicleTypeSpec(id="car"),
    "bus": VehicleTypeSpec(id="bus", base="bus", max_speed=27.0, accel=1.2, decel=4.0, tau=1.5),
    "truck": VehicleTypeSpec(id="truck", base="truck", max_speed=25.0, accel=1.3, decel=4.0, tau=1.5),
    "motorcycle": VehicleTypeSpec(id="motorcycle", base="motorcycle", accel=4.0, decel=7.0),
}
"""Types every scenario may name without declaring them."""


def _route_problems(item: Schema) -> list[tuple[Any, str]]:
    """Exactly one way to give the path: ``route`` (>= 1 roads) or origin and destination."""
    ends = [k for k in ("origin", "destination") if getattr(item, k) is not None]
    if getattr(item, "route", None) is not None:
        return [(ends[0], "not allowed with route: give either route or origin and destination")] if ends else []
    if not ends:
        return [((), "expected a route (a list of roads) or origin and destination, got neither")]
    return [
        (key, "required field missing (a road id)") for key in ("origin", "destination") if getattr(item, key) is None
    ]


def _rate_problems(item: Schema) -> list[tuple[Any, str]]:
    given = [k for k in ("rate", "probability") if getattr(item, k) is not None]
    if len(given) == 1:
        return []
    return [((), "expected exactly one of rate (vehicles per hour) or probability (departures per second), "
             f"got {'both' if given else 'neither'}")]  # fmt: skip


def _window_problems(item: Schema) -> list[tuple[Any, str]]:
    begin, end = item.begin, item.end  # type: ignore[attr-defined]
    if end <= begin:
        return [("end", f"expected a time after begin ({begin:g} s), got {end:g}")]
    return []


_ROUTE = Field(None, description="Consecutive roads, or some roads the route passes in order.")
_ORIGIN = Field(None, description="First road (with destination, instead of route).")
_DESTINATION = Field(None, description="Last road (with origin, instead of route).")
_VEHICLE_TYPE = Field("car", description="Declared in vehicle_types, or car, bus, truck, motorcycle.")
_DEPART_LANE = Field("best", description="best, random, free, first or a lane index.")
_DEPART_SPEED = Field(
    "desired", description="max, desired, random or a speed in m/s (at most the vehicle type's max_speed)."
)
_DEPART_POS = Field(0.0, description="Metres along the first road's lane.")


class FlowSpec(Spec):
    """Repeated departures: ``rate`` vehicles per hour (evenly spaced) or, instead, a departure
    ``probability`` each second. The path is ``route`` (consecutive roads, or just some roads
    the route passes in order) or ``origin`` and ``destination`` roads."""

    id: Text
    route: Annotated[list[Text], Field(min_length=1)] | None = _ROUTE
    origin: Text | None = _ORIGIN
    destination: Text | None = _DESTINATION
    rate: Rate | None = Field(None, description=f"Vehicles per hour (evenly spaced), at most {MAX_FLOW_RATE:,.0f}.")
    probability: Probability | None = Field(None, description="Departures per second.")
    begin: Time = Field(0.0, description="s.")
    end: Time = Field(3600.0, description="s, after begin.")
    vehicle_type: Text = _VEHICLE_TYPE
    depart_lane: DepartLane = _DEPART_LANE
    depart_speed: DepartSpeed = _DEPART_SPEED
    depart_pos: NonNegative = _DEPART_POS

    @model_validator(mode="after")
    def _consistent(self) -> FlowSpec:
        problems = _route_problems(self) + _rate_problems(self) + _window_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self

    @property
    def roads(self) -> list[str]:
        """The roads the vehicle must pass, in order (at least origin and destination)."""
        return list(self.route) if self.route else [self.origin, self.destination]


class TripSpec(Spec):
    """One vehicle departing at ``depart`` seconds; its id in the vehicle table is ``id``."""

    id: Text
    route: Annotated[list[Text], Field(min_length=1)] | None = _ROUTE
    origin: Text | None = _ORIGIN
    destination: Text | None = _DESTINATION
    depart: Time = Field(0.0, description="s.")
    vehicle_type: Text = _VEHICLE_TYPE
    depart_lane: DepartLane = _DEPART_LANE
    depart_speed: DepartSpeed = _DEPART_SPEED
    depart_pos: NonNegative = _DEPART_POS

    @model_validator(mode="after")
    def _consistent(self) -> TripSpec:
        problems = _route_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self

    @property
    def roads(self) -> list[str]:
        return list(self.route) if self.route else [self.origin, self.destination]


class PedestrianFlowSpec(Spec):
    """People walking from ``origin`` to ``destination`` road (on their sidewalks, through the
    crossings), SUMO engine only."""

    id: Text
    origin: Text
    destination: Text
    rate: Rate | None = Field(None, description=f"People per hour, at most {MAX_FLOW_RATE:,.0f}.")
    probability: Probability | None = Field(None, description="Departures per second.")
    begin: Time = 0.0
    end: Time = 3600.0
    speed: Annotated[float, Field(gt=0, le=MAX_WALKING_SPEED, allow_inf_nan=False)] = Field(
        1.3, description=f"Walking speed, m/s, at most {MAX_WALKING_SPEED:g}."
    )

    @model_validator(mode="after")
    def _consistent(self) -> PedestrianFlowSpec:
        problems = _rate_problems(self) + _window_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self


class TrafficSpec(Spec):
    """Who else is on the road, for either traffic engine."""

    engine: Literal[TRAFFIC_ENGINES] = "builtin"  # type: ignore[valid-type]
    density: Literal[DENSITY_LEVELS] = Field(  # type: ignore[valid-type]
        "none", description="Generated flows between all entry and exit roads, on top of the listed flows."
    )
    vehicle_types: dict[Text, VehicleTypeSpec] = Field(default_factory=dict, description="type name -> parameters")
    flows: list[FlowSpec] = Field(default_factory=list)
    trips: list[TripSpec] = Field(default_factory=list)
    pedestrians: list[PedestrianFlowSpec] = Field(default_factory=list, description="SUMO only.")

    @model_validator(mode="before")
    @classmethod
    def _type_names(cls, data: Any) -> Any:
        """A file names each vehicle type by its key only: that is its id."""
        types = data.get("vehicle_types") if isinstance(data, dict) else None
        if isinstance(types, dict):
            named = [name for name, vtype in types.items() if isinstance(vtype, dict) and "id" in vtype]
            if named:  # a file names a type by its key only
                raise field_errors(cls, [
                    (("vehicle_types", name, "id"), f"unknown field (a vehicle type's name is its key, {name!r})")
                    for name in named
                ])  # fmt: skip
            data = {
                **data,
                "vehicle_types": {
                    name: {"id": name, **vtype} if isinstance(vtype, dict) else vtype for name, vtype in types.items()
                },
            }
        return data

    @model_validator(mode="after")
    def _consistent(self) -> TrafficSpec:
        problems: list[tuple[Any, str]] = [
            (("vehicle_types", name, "id"), f"expected the type's key {name!r}, got {vtype.id!r}")
            for name, vtype in self.vehicle_types.items()
            if vtype.id != name
        ]
        for key, items in (("flows", self.flows), ("trips", self.trips)):
            for i, item in enumerate(items):
                name = item.vehicle_type
                if name not in self.vehicle_types and name not in DEFAULT_VEHICLE_TYPES:
                    problems.append(((key, i, "vehicle_type"), (
                        f"unknown vehicle type {name!r}; declared in traffic.vehicle_types: "
                        f"{', '.join(self.vehicle_types) or 'none'}; always available: {', '.join(DEFAULT_VEHICLE_TYPES)}"
                    )))  # fmt: skip
                    continue
                vtype = self.vehicle_type(name)
                speed = item.depart_speed
                if not isinstance(speed, str) and speed > vtype.max_speed:
                    problems.append(((key, i, "depart_speed"), (
                        f"expected at most vehicle type {name!r}'s max_speed ({vtype.max_speed:g} m/s), got {speed:g}"
                    )))  # fmt: skip
        departures = [("flows", i, f.id) for i, f in enumerate(self.flows)]
        departures += [("trips", i, t.id) for i, t in enumerate(self.trips)]
        problems += _duplicates(departures, "flows and trips")
        problems += _duplicates([("pedestrians", i, p.id) for i, p in enumerate(self.pedestrians)], "pedestrian flows")
        if self.pedestrians and self.engine != "sumo":
            problems.append((
                "pedestrians",
                f"pedestrians need engine: sumo (the {self.engine} engine has none), got engine {self.engine!r}",
            ))  # fmt: skip
        if problems:
            raise field_errors(self, problems)
        return self

    def vehicle_type(self, name: str) -> VehicleTypeSpec:
        """A declared type, or one of ``DEFAULT_VEHICLE_TYPES``."""
        if name in self.vehicle_types:
            return self.vehicle_types[name]
        return DEFAULT_VEHICLE_TYPES[name]


def _duplicates(ids: list[tuple[str, int, str]], among: str) -> list[tuple[Any, str]]:
    seen: dict[str, str] = {}
    problems: list[tuple[Any, str]] = []
    for key, i, item_id in ids:
        if item_id in seen:
            problems.append(((key, i, "id"), f"duplicate id {item_id!r} among {among} (also {seen[item_id]})"))
        else:
            seen[item_id] = f"traffic.{key}[{i}].id"
    return problems
