"""The agent interface: which sensors an agent has and how big their outputs are.

An agent's observation space is derived from its interface alone, so two agents with equal
interfaces share one space and are observed in one batched pass. The default interface gives the
basic observation (``smarts.sensors.observation``) with its historical keys and shapes; every
optional sensor adds keys or trailing feature columns, never changes the default ones.

Plain data only (no simulator imports): the scenario reader builds these from YAML with
``interface_from_dict`` and writes them back with ``interface_to_dict``.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field, fields
from typing import Any

from smarts.core.errors import InterfaceError

RASTER_LAYERS = ("drivable", "lanes", "route", "occupancy", "occlusion")
"""Raster layers an interface may ask for, drawn in the order the interface lists them."""
OCCLUSION_MODES = ("hide", "flag")
"""hide: fully hidden road users are left out of ``neighbours``; flag: they stay, with visible
fraction 0."""


def _positive_int(where: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InterfaceError(where, f"expected a positive integer, got {value!r}")


def _number(where: str, value: Any, *, positive: bool = False) -> None:
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    if not ok or (positive and value <= 0) or (not positive and value < 0):
        kind = "a positive number" if positive else "a non-negative number"
        raise InterfaceError(where, f"expected {kind}, got {value!r}")


def _flag(where: str, value: Any) -> None:
    if not isinstance(value, bool):
        raise InterfaceError(where, f"expected true or false, got {value!r}")


@dataclass(frozen=True)
class EgoInterface:
    extended: bool = False
    """Append the angular acceleration (rad/s^2) to ``ego`` (13 features instead of 12)."""

    def __post_init__(self) -> None:
        _flag("interface.ego.extended", self.extended)


@dataclass(frozen=True)
class NeighboursInterface:
    count: int = 8
    radius: float = 50.0
    """Metres from the ego's centre to a road user's centre."""
    extended: bool = False
    """Append speed, acceleration, yaw rate, lane index, same-road flag and a type one-hot."""

    def __post_init__(self) -> None:
        _positive_int("interface.neighbours.count", self.count)
        _number("interface.neighbours.radius", self.radius, positive=True)
        _flag("interface.neighbours.extended", self.extended)


@dataclass(frozen=True)
class WaypointsInterface:
    count: int = 20
    spacing: int = 2
    """Route points (about 1 m apart) between two waypoints."""

    def __post_init__(self) -> None:
        _positive_int("interface.waypoints.count", self.count)
        _positive_int("interface.waypoints.spacing", self.spacing)


@dataclass(frozen=True)
class OcclusionInterface:
    enabled: bool = False
    mode: str = "hide"
    range: float = 50.0
    """Sensor range (m): nothing farther from the ego's centre is visible."""

    def __post_init__(self) -> None:
        _flag("interface.occlusion.enabled", self.enabled)
        if self.mode not in OCCLUSION_MODES:
            raise InterfaceError(
                "interface.occlusion.mode", f"expected one of {', '.join(OCCLUSION_MODES)}, got {self.mode!r}"
            )
        _number("interface.occlusion.range", self.range, positive=True)


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
        _positive_int("interface.rasters.size", self.size)
        if self.size > 1024:
            raise InterfaceError("interface.rasters.size", f"expected at most 1024 pixels, got {self.size}")
        _number("interface.rasters.resolution", self.resolution, positive=True)
        if not isinstance(self.layers, tuple):
            raise InterfaceError("interface.rasters.layers", f"expected a list of layer names, got {self.layers!r}")
        for i, name in enumerate(self.layers):
            if name not in RASTER_LAYERS:
                raise InterfaceError(
                    f"interface.rasters.layers[{i}]", f"expected one of {', '.join(RASTER_LAYERS)}, got {name!r}"
                )
            if name in self.layers[:i]:
                raise InterfaceError(f"interface.rasters.layers[{i}]", f"{name!r} is listed twice")
        _flag("interface.rasters.rgb", self.rgb)
        if not self.layers and not self.rgb:
            raise InterfaceError("interface.rasters", "expected at least one layer or rgb: true")


@dataclass(frozen=True)
class LidarInterface:
    rays: int = 64
    """Evenly spaced over 360 degrees, ray 0 straight ahead, counter-clockwise."""
    range: float = 30.0
    noise: float = 0.0
    """Standard deviation (m) of Gaussian noise on hit distances, seeded from the scenario seed."""

    def __post_init__(self) -> None:
        _positive_int("interface.lidar.rays", self.rays)
        _number("interface.lidar.range", self.range, positive=True)
        _number("interface.lidar.noise", self.noise)


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
        _flag("interface.signals", self.signals)
        _flag("interface.lead", self.lead)
        _flag("interface.ahead", self.ahead)

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
    """Validate plain data (as loaded from YAML) into an interface; errors name ``path.field``."""
    if not isinstance(data, dict):
        raise InterfaceError(path, f"expected a mapping of sensors, got {data!r}")
    _known(data, path, (*_PARTS, *_FLAGS))
    kwargs: dict[str, Any] = {}
    try:
        for name, cls in _PARTS.items():
            if name not in data:
                continue
            value = data[name]
            if name in _OPTIONAL_PARTS and (value is None or value is False):
                kwargs[name] = None
                continue
            if name in _OPTIONAL_PARTS and value is True:
                value = {}
            kwargs[name] = _part(cls, value, f"interface.{name}")
        for name in _FLAGS:
            if name in data:
                kwargs[name] = data[name]
        return AgentInterface(**kwargs)
    except InterfaceError as err:
        raise InterfaceError(path + err.path[len("interface") :], err.problem) from None


def _known(data: dict, path: str, allowed: tuple[str, ...]) -> None:
    for key in data:
        if key not in allowed:
            hint = difflib.get_close_matches(str(key), allowed, n=1)
            suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
            raise InterfaceError(f"{path}.{key}", f"unknown field{suggestion}; allowed fields: {', '.join(allowed)}")


def _part(cls: type, value: Any, path: str) -> Any:
    if not isinstance(value, dict):
        raise InterfaceError(path, f"expected a mapping, got {value!r}")
    names = tuple(f.name for f in fields(cls))
    _known(value, path, names)
    kwargs = dict(value)
    if "layers" in kwargs:
        if not isinstance(kwargs["layers"], list):
            raise InterfaceError(f"{path}.layers", f"expected a list of layer names, got {kwargs['layers']!r}")
        kwargs["layers"] = tuple(kwargs["layers"])
    for f in fields(cls):  # YAML integers are fine where metres are expected
        if f.type == "float" and isinstance(kwargs.get(f.name), int) and not isinstance(kwargs[f.name], bool):
            kwargs[f.name] = float(kwargs[f.name])
    return cls(**kwargs)


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
