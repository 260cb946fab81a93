"""What a scenario holds, as plain dataclasses: map, agents and their missions, events, rewards,
traffic (``smarts.core.spec.traffic``) and comms.

Every layer may read these; reading them from YAML (with strict validation) and writing them back is
the scenario package's job (``smarts.scenario``, whose ``ScenarioSpec`` is this one plus
``from_yaml``/``from_dict``/``to_yaml``/``to_dict``, ``map_path`` and ``check_map``). An agent's
interface (``smarts.sensors.interface``) and the comms settings (``smarts.comms.config``) are owned
by their packages and only named here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from smarts.core.spec.replay import ReplaySpec
from smarts.core.spec.traffic import TrafficSpec
from smarts.core.vehicle_table import VEHICLE_DIMENSIONS, VehicleType

if TYPE_CHECKING:
    from smarts.comms.config import CommsConfig
    from smarts.sensors.interface import AgentInterface

BUILTIN_PREFIX = "builtin:"
"""A scenario's ``map`` naming a built-in map: ``builtin:<name>``."""

ACTION_SPACES = ("relative_target_pose", "target_pose", "continuous", "lane")
CONTROLLERS = ("direct", "lane_relative")
"""How an agent's actions reach its action space: ``direct`` (the space's own actions) or
``lane_relative`` (target-speed and lane-change commands turned into that space's actions by
``smarts.dynamics.lane_relative``)."""
LANE_RELATIVE_SPACES = ("relative_target_pose", "target_pose", "continuous")
TERMINATION_EVENTS = (
    "collision",
    "off_road",
    "partial_off_road",
    "wrong_way",
    "off_route",
    "reached_goal",
    "not_moving",
    "max_steps",
)
DEFAULT_TERMINATE_ON = ("collision", "off_road", "reached_goal", "max_steps")
MISSION_END_ACTIONS = ("remove", "traffic")
"""What happens to an agent's vehicle when its mission ends: it leaves, or traffic drives it on."""


@dataclass(frozen=True)
class VehicleDimensions:
    length: float
    width: float
    height: float
    mass: float


VEHICLE_TYPES: dict[str, VehicleDimensions] = {
    t.name.lower(): VehicleDimensions(*VEHICLE_DIMENSIONS[t])
    for t in VehicleType
    if t not in (VehicleType.PEDESTRIAN, VehicleType.BICYCLE)
}
"""Typical dimensions (m) and mass (kg) per vehicle type; a scenario may override each one."""


# ---------------------------------------------------------------------------- dataclasses
@dataclass
class VehicleSpec:
    type: str = "passenger"
    length: float | None = None
    width: float | None = None
    height: float | None = None
    mass: float | None = None

    def dimensions(self) -> VehicleDimensions:
        """The type's defaults with this spec's overrides applied."""
        base = VEHICLE_TYPES[self.type]
        return VehicleDimensions(
            length=base.length if self.length is None else self.length,
            width=base.width if self.width is None else self.width,
            height=base.height if self.height is None else self.height,
            mass=base.mass if self.mass is None else self.mass,
        )


@dataclass
class StartSpec:
    road: str | None = None
    """None only when ``take_over`` names the vehicle to start in."""
    lane: int = 0
    offset: float = 0.0
    """Metres along the lane from its start."""
    speed: float = 0.0
    heading: float | None = None
    """Radians; None means along the lane."""
    take_over: str | None = None
    """Id of a traffic trip departing at 0 whose vehicle the agent drives from reset on; the start
    pose is then that vehicle's, so road, lane, offset, speed and heading are not given."""


@dataclass
class GoalSpec:
    """Exactly one kind of goal: a position with a radius, a road (and lane), or endless driving."""

    position: tuple[float, float] | None = None
    radius: float = 3.0
    road: str | None = None
    lane: int | None = None
    """None: any lane of the road."""
    offset: float | None = None
    """Metres along the goal lane that must be reached; None: entering the road is enough."""
    endless: bool = False

    @property
    def kind(self) -> str:
        if self.endless:
            return "endless"
        return "position" if self.position is not None else "road"


@dataclass
class MissionSpec:
    start: StartSpec
    goal: GoalSpec
    route_via: list[str] = field(default_factory=list)
    on_end: str = "remove"
    """``remove``: the vehicle leaves when the mission ends; ``traffic``: traffic drives it on."""
    follow: str | None = None
    """Id of the vehicle this agent follows (a traffic trip or another agent): the lead of the
    following task, seen in the ``lead`` observation block and scored by SFD. None: no lead."""


@dataclass
class AgentSpec:
    id: str
    mission: MissionSpec
    action_space: str = "relative_target_pose"
    controller: str = "direct"
    """``direct``: actions are the action space's own; ``lane_relative``: (acceleration, lane
    change) commands that ``smarts.dynamics.lane_relative`` turns into the action space's actions."""
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)
    policy: str | None = None
    """Zoo locator (``zoo:keep-lane`` or ``keep-lane``) of the policy that drives this agent inside
    the simulator: a social agent, not controlled by the learner. None: a learning agent."""
    interface: AgentInterface | None = None
    """Which sensors the agent has (``smarts.sensors.interface``); None: the default interface."""

    @property
    def is_social(self) -> bool:
        return self.policy is not None


@dataclass
class EventsSpec:
    terminate_on: list[str] = field(default_factory=lambda: list(DEFAULT_TERMINATE_ON))
    not_moving_seconds: float = 60.0
    not_moving_distance: float = 1.0
    """A vehicle that moved less than this many metres in ``not_moving_seconds`` is not moving."""


@dataclass
class RewardSpec:
    progress_weight: float = 1.0
    """Reward per metre of progress along the route."""
    collision_penalty: float = 10.0
    off_road_penalty: float = 10.0
    goal_bonus: float = 10.0
    step_penalty: float = 0.0
    """Subtracted every step, to favour reaching the goal sooner."""


@dataclass
class ScenarioSpec:
    """A whole scenario, as read from its YAML file by ``smarts.scenario`` (which validates every
    field once, so the simulator can trust them)."""

    name: str
    map: str
    """``builtin:<name>`` or a .net.xml/.xodr path relative to the scenario file's folder."""
    agents: list[AgentSpec]
    step_length: float = 0.1
    episode_steps: int = 1000
    seed: int = 42
    vehicle_capacity: int = 256
    events: EventsSpec = field(default_factory=EventsSpec)
    reward: RewardSpec = field(default_factory=RewardSpec)
    traffic: TrafficSpec | None = None
    """Flows, trips, vehicle types and pedestrians for a traffic engine; None: agents only."""
    comms: CommsConfig | None = None
    """V2V messaging between agents and connected traffic (``smarts.comms``); None: comms off, the
    action and observation spaces have no message parts."""
    replay: ReplaySpec | None = None
    """Recorded traffic replayed from a dataset (``smarts.replay``); None: no replay."""
    source: str = field(default="<dict>", compare=False, repr=False)
    """Where the spec was read from; prefixes every error message."""
    base_dir: Path | None = field(default=None, compare=False, repr=False)
    """Folder that relative map paths are resolved against (the scenario file's folder)."""

    @property
    def agent_ids(self) -> list[str]:
        return [a.id for a in self.agents]

    @property
    def social_agent_ids(self) -> list[str]:
        """Agents driven by a zoo policy inside the simulator, not by the learner."""
        return [a.id for a in self.agents if a.policy is not None]

    @property
    def builtin_map(self) -> str | None:
        """Name of the built-in map, or None when the map is a file."""
        return self.map[len(BUILTIN_PREFIX) :] if self.map.startswith(BUILTIN_PREFIX) else None
