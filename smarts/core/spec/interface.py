"""The agent interface: which sensors an agent has and how big their outputs are.

An agent's observation space is derived from its interface alone, so two agents with equal
interfaces share one space and are observed in one batched pass (the models are frozen and
hashable). The default interface gives the basic observation (``smarts.sensors.observation``) with
its historical keys and shapes; every optional sensor adds keys or trailing feature columns, never
changes the default ones.

The same models are an agent's ``interface:`` section in a scenario file and what the sensors read;
built in code they are checked by the same rules, and a problem raises ``InterfaceError`` naming the
dotted field (``interface.lidar.rays``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Literal

from pydantic import BeforeValidator, Field, ValidationError, model_validator

from smarts.core.errors import InterfaceError
from smarts.core.schema import Schema, field_errors, locate
from smarts.core.spec.base import AsList, AsTuple, Spec

RASTER_LAYERS = ("drivable", "lanes", "route", "occupancy", "occlusion")
"""Raster layers an interface may ask for, drawn in the order the interface lists them."""
OCCLUSION_MODES = ("hide", "flag")
"""hide: fully hidden road users are left out of ``neighbours``; flag: they stay, with visible
fraction 0."""

Count = Annotated[int, Field(ge=1)]
Metres = Annotated[float, Field(gt=0, allow_inf_nan=False)]


def interface_problem(exc: ValidationError, model: type[Schema], path: str) -> InterfaceError:
    """Every problem of ``exc`` under ``path``: the error names the first field, its message lists
    the others on their own lines (each ``path: problem``)."""
    found = [locate(model, p) for p in exc.errors()]
    lines = [(f"{path}.{where}" if where else path, message) for where, message in found]
    (first_path, first), rest = lines[0], lines[1:]
    return InterfaceError(first_path, "\n".join([first, *(f"{where}: {message}" for where, message in rest)]))


class _Part(Spec):
    path: ClassVar[str] = "interface"
    """Where the section sits in an agent's interface (names the field in errors)."""

    @classmethod
    def code_error(cls, exc: ValidationError) -> Exception:
        return interface_problem(exc, cls, cls.path)


class EgoInterface(_Part):
    """The ego block (``ego``)."""

    path: ClassVar[str] = "interface.ego"
    extended: bool = Field(
        False, description="Append the angular acceleration (rad/s^2) to ``ego`` (13 features instead of 12)."
    )


class NeighboursInterface(_Part):
    """The nearest road users (``neighbours``)."""

    path: ClassVar[str] = "interface.neighbours"
    count: Count = Field(8, description="Road users in the block (its fixed size).")
    radius: Metres = Field(50.0, description="Metres from the ego's centre to a road user's centre.")
    extended: bool = Field(
        False,
        description="Append speed, acceleration, yaw rate, lane index, same-road flag and a type one-hot.",
    )


class WaypointsInterface(_Part):
    """Points along the route's lanes (``waypoints``)."""

    path: ClassVar[str] = "interface.waypoints"
    count: Count = Field(20, description="Waypoints per lane.")
    spacing: Count = Field(2, description="Route points (about 1 m apart) between two waypoints.")


class OcclusionInterface(_Part):
    """What the ego cannot see behind other road users."""

    path: ClassVar[str] = "interface.occlusion"
    enabled: bool = False
    mode: Literal["hide", "flag"] = Field(
        "hide",
        description="hide: fully hidden road users are left out of ``neighbours``; flag: they stay, "
        "with visible fraction 0.",
    )
    range: Metres = Field(50.0, description="Sensor range (m): nothing farther from the ego's centre is visible.")


class RasterInterface(_Part):
    """Top-down rasters around the ego (``rasters``, and ``rgb`` with ``rgb: true``)."""

    path: ClassVar[str] = "interface.rasters"
    size: Annotated[int, Field(ge=1, le=1024)] = Field(
        64, description="Pixels per side (square, ego at the centre, heading up)."
    )
    resolution: Metres = Field(0.5, description="Metres per pixel.")
    layers: Annotated[list[Literal["drivable", "lanes", "route", "occupancy", "occlusion"]], AsList, AsTuple] = Field(
        RASTER_LAYERS, description="Layers drawn, in this order."
    )
    rgb: bool = Field(False, description="Also give a composed uint8 [size, size, 3] top-down image.")

    @model_validator(mode="after")
    def _layers(self) -> RasterInterface:
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


class LidarInterface(_Part):
    """Simulated lidar (``lidar`` and ``lidar_hit``)."""

    path: ClassVar[str] = "interface.lidar"
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


class AgentInterface(_Part):
    """Which sensors are on and their sizes (every field optional). Hashable: agents with equal
    interfaces are observed together."""

    ego: EgoInterface = EgoInterface()
    neighbours: NeighboursInterface = NeighboursInterface()
    waypoints: WaypointsInterface = WaypointsInterface()
    occlusion: OcclusionInterface = OcclusionInterface()
    rasters: Annotated[RasterInterface | None, BeforeValidator(_switch)] = Field(
        None, description="Off unless given; true: on with the defaults."
    )
    lidar: Annotated[LidarInterface | None, BeforeValidator(_switch)] = Field(
        None, description="Off unless given; true: on with the defaults."
    )
    signals: bool = Field(True, description="The next traffic signal on the route (``signal``).")
    lead: bool = Field(
        False,
        description="The vehicle the agent follows (``mission.follow``) as its own block (``lead``): relative "
        "position, heading and velocity, speed, acceleration, gap along the lane, visible, in my lane.",
    )
    ahead: bool = Field(
        False,
        description="The nearest road user ahead on the agent's lane, whoever it is (``ahead``): present, gap "
        "along the lane, relative speed, speed, acceleration.",
    )

    @property
    def needs_shadows(self) -> bool:
        """Whether the occlusion depth buffer must be computed (occlusion, its layer or RGB)."""
        r = self.rasters
        return self.occlusion.enabled or (r is not None and (r.rgb or "occlusion" in r.layers))


OPTIONAL_PARTS = ("rasters", "lidar")


def interface_from_dict(data: Any, path: str = "interface") -> AgentInterface:
    """Validate plain data (as loaded from YAML) into an interface; problems raise
    ``InterfaceError`` naming ``path.field`` (every problem, one per line)."""
    if not isinstance(data, Mapping):
        raise InterfaceError(path, f"expected a mapping of sensors, got {data!r}")
    try:
        return AgentInterface.model_validate(dict(data))
    except ValidationError as exc:
        raise interface_problem(exc, AgentInterface, path) from None


def interface_to_dict(interface: AgentInterface) -> dict[str, Any]:
    """Plain data that ``interface_from_dict`` turns back into an equal interface (only the
    fields that differ from the defaults)."""
    out: dict[str, Any] = {}
    default = AgentInterface()
    for name in AgentInterface.model_fields:
        value = getattr(interface, name)
        if not isinstance(value, Spec):
            if value is None and name in OPTIONAL_PARTS:
                continue
            if value != getattr(default, name):
                out[name] = value
            continue
        base = getattr(default, name) or type(value)()
        changed = {
            key: list(part) if isinstance(part, tuple) else part
            for key in type(value).model_fields
            if (part := getattr(value, key)) != getattr(base, key)
        }
        if changed or name in OPTIONAL_PARTS:
            out[name] = changed
    return out
