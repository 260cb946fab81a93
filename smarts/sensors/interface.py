"""The agent interface: which sensors an agent has and how big their outputs are.

An agent's observation space is derived from its interface alone, so two agents with equal
interfaces share one space and are observed in one batched pass. The default interface gives the
basic observation (``smarts.sensors.observation``) with its historical keys and shapes; every
optional sensor adds keys or trailing feature columns, never changes the default ones.

Plain data only (no simulator imports). What an ``interface:`` section may say is the schema model
``InterfaceFile`` (``smarts.core.schema``): the scenario reader composes it into an agent's section,
``interface_from_dict`` validates a section on its own, ``interface_to_dict`` writes one back, and
the dataclasses check values built in code against the same models.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, ValidationError, model_validator

from smarts.core.errors import InterfaceError
from smarts.core.schema import Schema, field_errors, locate

RASTER_LAYERS = ("drivable", "lanes", "route", "occupancy", "occlusion")
"""Raster layers an interface may ask for, drawn in the order the interface lists them."""
OCCLUSION_MODES = ("hide", "flag")
"""hide: fully hidden road users are left out of ``neighbours``; flag: they stay, with visible
fraction 0."""

# ----------------------------------------------------------------------------- file layout
Count = Annotated[int, Field(ge=1)]
Metres = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class EgoFile(Schema):
    """The ego block (``ego``)."""

    extended: bool = Field(
        False, description="Append the angular acceleration (rad/s^2) to ``ego`` (13 features instead of 12)."
    )


class NeighboursFile(Schema):
    """The nearest road users (``neighbours``)."""

    count: Count = Field(8, description="Road users in the block (its fixed size).")
    radius: Metres = Field(50.0, description="Metres from the ego's centre to a road user's centre.")
    extended: bool = Field(
        False,
        description="Append speed, acceleration, yaw rate, lane index, same-road flag and a type one-hot.",
    )


class WaypointsFile(Schema):
    """Points along the route's lanes (``waypoints``)."""

    count: Count = Field(20, description="Waypoints per lane.")
    spacing: Count = Field(2, description="Route points (about 1 m apart) between two waypoints.")


class OcclusionFile(Schema):
    """What the ego cannot see behind other road users."""

    enabled: bool = False
    mode: Literal["hide", "flag"] = Field(
        "hide",
        description="hide: fully hidden road users are left out of ``neighbours``; flag: they stay, "
        "with visible fraction 0.",
    )
    range: Metres = Field(50.0, description="Sensor range (m): nothing farther from the ego's centre is visible.")


class RastersFile(Schema):
    """Top-down rasters around the ego (``rasters``, and ``rgb`` with ``rgb: true``)."""

    size: Annotated[int, Field(ge=1, le=1024)] = Field(
        64, description="Pixels per side (square, ego at the centre, heading up)."
    )
    resolution: Metres = Field(0.5, description="Metres per pixel.")
    layers: list[Literal["drivable", "lanes", "route", "occupancy", "occlusion"]] = Field(
        default_factory=lambda: list(RASTER_LAYERS), description="Layers drawn, in this order."
    )
    rgb: bool = Field(False, description="Also give a composed uint8 [size, size, 3] top-down image.")

    @model_validator(mode="after")
    def _layers(self) -> RastersFile:
        problems: list[tuple[Any, str]] = [
            (("layers", i), f"{name!r} is listed twice")
            for i, name in enumerate(self.layers)
            if name in self.layers[:i]
        ]
        if not self.layers and not self.rgb:
            problems.append(((), "expected at least one layer or rgb: true"))
        if problems:
            raise field_errors(self, problems)
        return self


class LidarFile(Schema):
    """Simulated lidar (``lidar`` and ``lidar_hit``)."""

    rays: Count = Field(64, description="Evenly spaced over 360 degrees, ray 0 straight ahead, counter-clockwise.")
    range: Metres = 30.0
    noise: Annotated[float, Field(ge=0, allow_inf_nan=False)] = Field(
        0.0, description="Standard deviation (m) of Gaussian noise on hit distances, seeded from the scenario seed."
    )


def _switch(value: Any) -> Any:
    """An optional sensor: ``true`` turns it on with its defaults, ``false`` (or null) leaves it off."""
    if value is True:
        return {}
    if value is False:
        return None
    return value


class InterfaceFile(Schema):
    """An agent's ``interface:`` section: which sensors are on and their sizes (every field optional)."""

    ego: EgoFile = EgoFile()
    neighbours: NeighboursFile = NeighboursFile()
    waypoints: WaypointsFile = WaypointsFile()
    occlusion: OcclusionFile = OcclusionFile()
    rasters: Annotated[RastersFile | None, BeforeValidator(_switch)] = Field(
        None, description="Off unless given; true: on with the defaults."
    )
    lidar: Annotated[LidarFile | None, BeforeValidator(_switch)] = Field(
        None, description="Off unless given; true: on with the defaults."
    )
    signals: bool = Field(True, description="The next traffic signal on the route (``signal``).")
    lead: bool = Field(
        False, description="The vehicle the agent follows (``mission.follow``) as its own block (``lead``)."
    )
    ahead: bool = Field(False, description="The nearest road user ahead on the agent's lane (``ahead``).")

    def to_interface(self) -> AgentInterface:
        """The validated section as the simulator's dataclass."""
        rasters = self.rasters
        return AgentInterface(
            ego=EgoInterface(**self.ego.model_dump()),
            neighbours=NeighboursInterface(**self.neighbours.model_dump()),
            waypoints=WaypointsInterface(**self.waypoints.model_dump()),
            occlusion=OcclusionInterface(**self.occlusion.model_dump()),
            rasters=None
            if rasters is None
            else RasterInterface(**{**rasters.model_dump(), "layers": tuple(rasters.layers)}),
            lidar=None if self.lidar is None else LidarInterface(**self.lidar.model_dump()),
            signals=self.signals,
            lead=self.lead,
            ahead=self.ahead,
        )


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python number it holds (values built in code may be either)."""
    return value.item() if type(value).__module__ == "numpy" and hasattr(value, "item") else value


def _problem(exc: ValidationError, model: type[Schema], path: str) -> InterfaceError:
    """Every problem of ``exc`` under ``path``: the error names the first field, its message lists
    the others on their own lines (each ``path: problem``)."""
    found = [locate(model, p) for p in exc.errors()]
    lines = [(f"{path}.{where}" if where else path, message) for where, message in found]
    (first_path, first), rest = lines[0], lines[1:]
    return InterfaceError(first_path, "\n".join([first, *(f"{where}: {message}" for where, message in rest)]))


def _check(model: type[Schema], part: Any, path: str) -> None:
    """Validate a dataclass built in code against its file model (the same rules as YAML)."""
    values = {f.name: _plain(getattr(part, f.name)) for f in fields(part) if f.name in model.model_fields}
    try:
        model.model_validate(values)
    except ValidationError as exc:
        raise _problem(exc, model, path) from None


# ----------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class EgoInterface:
    extended: bool = False
    """Append the angular acceleration (rad/s^2) to ``ego`` (13 features instead of 12)."""

    def __post_init__(self) -> None:
        _check(EgoFile, self, "interface.ego")


@dataclass(frozen=True)
class NeighboursInterface:
    count: int = 8
    radius: float = 50.0
    """Metres from the ego's centre to a road user's centre."""
    extended: bool = False
    """Append speed, acceleration, yaw rate, lane index, same-road flag and a type one-hot."""

    def __post_init__(self) -> None:
        _check(NeighboursFile, self, "interface.neighbours")


@dataclass(frozen=True)
class WaypointsInterface:
    count: int = 20
    spacing: int = 2
    """Route points (about 1 m apart) between two waypoints."""

    def __post_init__(self) -> None:
        _check(WaypointsFile, self, "interface.waypoints")


@dataclass(frozen=True)
class OcclusionInterface:
    enabled: bool = False
    mode: str = "hide"
    range: float = 50.0
    """Sensor range (m): nothing farther from the ego's centre is visible."""

    def __post_init__(self) -> None:
        _check(OcclusionFile, self, "interface.occlusion")


@dataclass(frozen=True)
class RasterInterface:
    size: int = 64
    """Pixels per side (square, ego at the centre, heading up)."""
    resolution: float = 0.5
    """Metres per pixel."""
    layers: tuple[str, ...] = RASTER_LAYERS
    rgb: bool = False
    """Also give a composed uint8 [size, size, 3] top-down image."""

    def __post_init__(self) -> None:
        if not isinstance(self.layers, tuple):  # a tuple keeps the interface hashable
            raise InterfaceError("interface.rasters.layers", f"expected a tuple of layer names, got {self.layers!r}")
        values = {f.name: _plain(getattr(self, f.name)) for f in fields(self)}
        try:
            RastersFile.model_validate({**values, "layers": list(self.layers)})
        except ValidationError as exc:
            raise _problem(exc, RastersFile, "interface.rasters") from None


@dataclass(frozen=True)
class LidarInterface:
    rays: int = 64
    """Evenly spaced over 360 degrees, ray 0 straight ahead, counter-clockwise."""
    range: float = 30.0
    noise: float = 0.0
    """Standard deviation (m) of Gaussian noise on hit distances, seeded from the scenario seed."""

    def __post_init__(self) -> None:
        _check(LidarFile, self, "interface.lidar")


@dataclass(frozen=True)
class AgentInterface:
    """Which sensors are on. Hashable: agents with equal interfaces are observed together."""

    ego: EgoInterface = field(default_factory=EgoInterface)
    neighbours: NeighboursInterface = field(default_factory=NeighboursInterface)
    waypoints: WaypointsInterface = field(default_factory=WaypointsInterface)
    occlusion: OcclusionInterface = field(default_factory=OcclusionInterface)
    rasters: RasterInterface | None = None
    lidar: LidarInterface | None = None
    signals: bool = True
    """The next traffic signal on the route (``signal``)."""
    lead: bool = False
    """The vehicle the agent follows (``mission.follow``) as its own block (``lead``): relative
    position, heading and velocity, speed, acceleration, gap along the lane, visible, in my lane."""
    ahead: bool = False
    """The nearest road user ahead on the agent's lane, whoever it is (``ahead``): present, gap
    along the lane, relative speed, speed, acceleration."""

    def __post_init__(self) -> None:
        values = {name: _plain(getattr(self, name)) for name in _FLAGS}
        try:
            InterfaceFile.model_validate(values)
        except ValidationError as exc:
            raise _problem(exc, InterfaceFile, "interface") from None

    @property
    def needs_shadows(self) -> bool:
        """Whether the occlusion depth buffer must be computed (occlusion, its layer or RGB)."""
        r = self.rasters
        return self.occlusion.enabled or (r is not None and (r.rgb or "occlusion" in r.layers))


_PARTS: dict[str, type] = {
    "ego": EgoInterface,
    "neighbours": NeighboursInterface,
    "waypoints": WaypointsInterface,
    "occlusion": OcclusionInterface,
    "rasters": RasterInterface,
    "lidar": LidarInterface,
}
_OPTIONAL_PARTS = ("rasters", "lidar")
_FLAGS = ("signals", "lead", "ahead")


def interface_from_dict(data: Any, path: str = "interface") -> AgentInterface:
    """Validate plain data (as loaded from YAML) into an interface (``InterfaceFile``); problems
    raise ``InterfaceError`` naming ``path.field`` (every problem, one per line)."""
    if not isinstance(data, Mapping):
        raise InterfaceError(path, f"expected a mapping of sensors, got {data!r}")
    try:
        section = InterfaceFile.model_validate(dict(data))
    except ValidationError as exc:
        raise _problem(exc, InterfaceFile, path) from None
    return section.to_interface()


def interface_to_dict(interface: AgentInterface) -> dict[str, Any]:
    """Plain data that ``interface_from_dict`` turns back into an equal interface (only the
    fields that differ from the defaults)."""
    out: dict[str, Any] = {}
    default = AgentInterface()
    for name, cls in _PARTS.items():
        part = getattr(interface, name)
        if part is None:
            continue
        base = getattr(default, name) or cls()
        changed = {
            f.name: list(getattr(part, f.name)) if f.name == "layers" else getattr(part, f.name)
            for f in fields(cls)
            if getattr(part, f.name) != getattr(base, f.name)
        }
        if changed or name in _OPTIONAL_PARTS:
            out[name] = changed
    for name in _FLAGS:
        if getattr(interface, name) != getattr(default, name):
            out[name] = getattr(interface, name)
    return out
