"""Continuous action space (throttle, brake, steering) on real pybullet cars.

Each ``PhysicsWorld`` owns one pybullet client in DIRECT mode with a flat ground plane. A car is one
multibody: a box chassis (the base, whose frame is the centre of mass, low between the axles) and
four cylinder wheels on revolute axles, the axles ``wheelbase_for_length(length)`` apart; each front
wheel hangs on its own steering hinge (a revolute joint about the vertical). There is no suspension.

Control model (documented because agents learn it):
- steering in [-1, 1] (+ = left) sets the equivalent central wheel angle ``steering * max_steer``;
  the two front hinges follow it with Ackermann geometry through position-controlled motors.
- throttle in [0, 1] is a drive torque ``throttle * max_drive_torque`` split over the rear wheels;
  brake in [0, 1] is a brake torque ``brake * max_brake_torque`` split 35/35/15/15 % over the
  front/rear wheels (front bias keeps the rear from locking first); rolling resistance
  ``rolling_resistance * m * g`` always opposes rolling. Per wheel the net torque drives a velocity
  motor: toward ``max_wheel_speed`` when drive exceeds brake plus rolling resistance, toward
  standstill otherwise (holding the wheel like a brake, which also keeps a parked car still), with
  the net torque as its limit. Full brake on dry ground (friction 1) decelerates about 9 m/s^2.
- Bullet's built-in velocity damping is switched off (it acts like a large air drag); there is no
  aerodynamic drag.

pybullet's API is per body, so ``apply_controls`` and ``read_state`` loop over the handles;
everything else is vectorised. ``step`` advances ``dt`` in ``round(dt * physics_hz)`` physics steps.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
import pybullet as p

from smarts.core.vehicle_table import VehicleTable
from smarts.dynamics.action_spaces import ActionSpaceType, check_actions
from smarts.dynamics.bicycle import wheelbase_for_length

WHEEL_RADIUS = 0.33
WHEEL_WIDTH = 0.22
WHEEL_MASS = 20.0
HINGE_MASS = 5.0
CHASSIS_CLEARANCE = 0.3  # ground to the bottom of the chassis box, m
CENTRE_OF_MASS_ABOVE_AXLE = 0.15  # keeps cars from rolling over in hard turns

# Link order of every car (link index == joint index).
_HINGE_FL, _WHEEL_FL, _HINGE_FR, _WHEEL_FR, _WHEEL_RL, _WHEEL_RR = range(6)
_WHEELS = [_WHEEL_FL, _WHEEL_FR, _WHEEL_RL, _WHEEL_RR]
_HINGES = [_HINGE_FL, _HINGE_FR]
_DRIVEN = np.array([0.0, 0.0, 0.5, 0.5])  # rear-wheel drive: share of drive torque per wheel
# Share of brake torque per wheel: front-biased like real cars, so the (less loaded) rear wheels do
# not lock first and spin the car under full braking.
_BRAKED = np.array([0.35, 0.35, 0.15, 0.15])
_GRAVITY = 9.81


class ChassisState(NamedTuple):
    """Per-vehicle state arrays read back from the physics."""

    x: np.ndarray  # chassis box centre projected to the ground, m
    y: np.ndarray
    heading: np.ndarray  # rad, 0 = +x, counter-clockwise
    speed: np.ndarray  # signed forward speed, m/s
    yaw_rate: np.ndarray  # rad/s
    steering: np.ndarray  # mean front wheel angle, rad (+ = left)


def _chassis_mass(
    x: float, y: float, heading: float, speed: float, length: float, width: float, height: float, mass: float
) -> float:
    """The chassis's share of ``mass`` (the car less its wheels and hinges), after checking every argument."""
    for name, value in (("length", length), ("width", width), ("height", height)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"add_vehicle: {name} must be a positive number, got {value!r}")
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(heading)):
        raise ValueError(f"add_vehicle: pose must be finite, got ({x!r}, {y!r}, {heading!r})")
    if not math.isfinite(speed):
        raise ValueError(f"add_vehicle: speed must be finite, got {speed!r}")
    if height <= CHASSIS_CLEARANCE + 0.1:
        raise ValueError(f"add_vehicle: height must exceed {CHASSIS_CLEARANCE + 0.1} m, got {height!r}")
    chassis_mass = mass - 4.0 * WHEEL_MASS - 2.0 * HINGE_MASS
    if not (math.isfinite(mass) and chassis_mass > 0):
        raise ValueError(f"add_vehicle: mass must exceed {4 * WHEEL_MASS + 2 * HINGE_MASS} kg, got {mass!r}")
    return chassis_mass


def _create_car(
    cid: int, x: float, y: float, heading: float, length: float, width: float, height: float, chassis_mass: float
) -> tuple[int, float, float, float]:
    """One multibody: the chassis box, two steering hinges carrying the front wheels, two rear wheels.

    Returns the body and the geometry the controls need: wheelbase, half track, box centre above the base.
    """
    base_z = WHEEL_RADIUS + CENTRE_OF_MASS_ABOVE_AXLE
    box_centre_z = 0.5 * (CHASSIS_CLEARANCE + height)
    box_above_base = box_centre_z - base_z
    chassis = p.createCollisionShape(
        p.GEOM_BOX,
        halfExtents=[0.5 * length, 0.5 * width, 0.5 * (height - CHASSIS_CLEARANCE)],
        collisionFramePosition=[0.0, 0.0, box_above_base],
        physicsClientId=cid,
    )
    wheel = p.createCollisionShape(
        p.GEOM_CYLINDER,
        radius=WHEEL_RADIUS,
        height=WHEEL_WIDTH,
        collisionFrameOrientation=p.getQuaternionFromEuler([math.pi / 2, 0.0, 0.0]),
        physicsClientId=cid,
    )
    hinge = p.createCollisionShape(p.GEOM_SPHERE, radius=0.05, physicsClientId=cid)

    wheelbase = float(wheelbase_for_length(length))
    half_track = 0.5 * max(width - WHEEL_WIDTH, 0.5 * width)
    axle_z = WHEEL_RADIUS - base_z
    front, rear = 0.5 * wheelbase, -0.5 * wheelbase
    # Links: hinge FL, wheel FL (child of hinge), hinge FR, wheel FR, wheel RL, wheel RR.
    positions = [
        [front, half_track, axle_z],
        [0.0, 0.0, 0.0],
        [front, -half_track, axle_z],
        [0.0, 0.0, 0.0],
        [rear, half_track, axle_z],
        [rear, -half_track, axle_z],
    ]
    parents = [0, 1, 0, 3, 0, 0]  # 0 = base, i + 1 = link i
    axes = [[0, 0, 1], [0, 1, 0], [0, 0, 1], [0, 1, 0], [0, 1, 0], [0, 1, 0]]
    shapes = [hinge, wheel, hinge, wheel, wheel, wheel]
    masses = [HINGE_MASS, WHEEL_MASS, HINGE_MASS, WHEEL_MASS, WHEEL_MASS, WHEEL_MASS]
    identity = [0.0, 0.0, 0.0, 1.0]
    body = p.createMultiBody(
        baseMass=chassis_mass,
        baseCollisionShapeIndex=chassis,
        basePosition=[x, y, base_z],
        baseOrientation=p.getQuaternionFromEuler([0.0, 0.0, heading]),
        linkMasses=masses,
        linkCollisionShapeIndices=shapes,
        linkVisualShapeIndices=[-1] * 6,
        linkPositions=positions,
        linkOrientations=[identity] * 6,
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * 6,
        linkInertialFrameOrientations=[identity] * 6,
        linkParentIndices=parents,
        linkJointTypes=[p.JOINT_REVOLUTE] * 6,
        linkJointAxis=axes,
        physicsClientId=cid,
    )
    return body, wheelbase, half_track, box_above_base


class PhysicsWorld:
    """One pybullet world of cars on a flat ground plane, stepped ``dt`` seconds per ``step()``."""

    def __init__(
        self,
        dt: float = 0.1,
        physics_hz: float = 240.0,
        *,
        max_steer: float = 0.6,
        max_drive_torque: float = 2000.0,
        max_brake_torque: float = 4500.0,
        max_wheel_speed: float = 50.0 / WHEEL_RADIUS,
        steering_torque: float = 2000.0,
        friction: float = 1.0,
        rolling_resistance: float = 0.015,
        solver_iterations: int = 10,
    ):
        for name, value in (
            ("dt", dt),
            ("physics_hz", physics_hz),
            ("max_steer", max_steer),
            ("max_drive_torque", max_drive_torque),
            ("max_brake_torque", max_brake_torque),
            ("max_wheel_speed", max_wheel_speed),
            ("steering_torque", steering_torque),
            ("friction", friction),
            ("rolling_resistance", rolling_resistance),
        ):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"PhysicsWorld: {name} must be a positive number, got {value!r}")
        if not (isinstance(solver_iterations, int) and solver_iterations > 0):
            raise ValueError(f"PhysicsWorld: solver_iterations must be a positive int, got {solver_iterations!r}")
        self.dt = float(dt)
        self.substeps = max(1, int(round(dt * physics_hz)))
        self.max_steer = float(max_steer)
        self.max_drive_torque = float(max_drive_torque)
        self.max_brake_torque = float(max_brake_torque)
        self.max_wheel_speed = float(max_wheel_speed)
        self.steering_torque = float(steering_torque)
        self.friction = float(friction)
        self.rolling_resistance = float(rolling_resistance)
        self.solver_iterations = solver_iterations
        self._client = p.connect(p.DIRECT)
        if self._client < 0:
            raise RuntimeError("pybullet could not open a DIRECT physics client")
        self._setup()

    # ------------------------------------------------------------------ world
    def _setup(self) -> None:
        cid = self._client
        p.setGravity(0.0, 0.0, -9.81, physicsClientId=cid)
        p.setPhysicsEngineParameter(
            # Motor force limits are turned into impulses with the engine's time step, so the
            # engine must step at the true physics rate (substeps are looped in ``step``).
            fixedTimeStep=self.dt / self.substeps,
            numSolverIterations=self.solver_iterations,
            deterministicOverlappingPairs=1,
            physicsClientId=cid,
        )
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        self.ground = p.createMultiBody(0.0, plane, physicsClientId=cid)
        p.changeDynamics(self.ground, -1, lateralFriction=self.friction, restitution=0.0, physicsClientId=cid)
        # Per-handle geometry, indexed by the pybullet body id (small non-negative ints).
        self._wheelbase = np.zeros(16)
        self._half_track = np.zeros(16)
        self._box_above_base = np.zeros(16)
        self._rolling_torque = np.zeros(16)  # per wheel, N m
        self._mass = np.zeros(16)  # whole car, kg
        self._handles: set[int] = set()

    def step(self) -> None:
        """Advance the world by ``dt`` (``substeps`` physics steps)."""
        cid = self._client
        for _ in range(self.substeps):
            p.stepSimulation(physicsClientId=cid)

    def reset(self) -> None:
        """Remove every car; handles from before are invalid afterwards."""
        p.resetSimulation(physicsClientId=self._client)
        self._setup()

    def close(self) -> None:
        if self._client >= 0:
            p.disconnect(physicsClientId=self._client)
            self._client = -1

    def __enter__(self) -> PhysicsWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    @property
    def vehicle_count(self) -> int:
        return len(self._handles)

    # ------------------------------------------------------------------ vehicles
    def add_vehicle(
        self,
        x: float,
        y: float,
        heading: float,
        speed: float = 0.0,
        length: float = 4.5,
        width: float = 1.8,
        height: float = 1.5,
        mass: float = 1500.0,
    ) -> int:
        """Build a car with its box centre at (x, y) on the ground, moving forward at ``speed``.

        ``mass`` is the whole car; the wheels and hinges take their share of it. Returns the handle.
        """
        chassis_mass = _chassis_mass(x, y, heading, speed, length, width, height, mass)
        cid = self._client
        body, wheelbase, half_track, box_above_base = _create_car(
            cid, x, y, heading, length, width, height, chassis_mass
        )
        # Bullet's default damping acts like a strong air drag (60 v^2 N on a sedan): switch it off.
        p.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
        for link in _WHEELS:
            p.changeDynamics(body, link, lateralFriction=self.friction, restitution=0.0, physicsClientId=cid)
        if speed != 0.0:
            c, s = math.cos(heading), math.sin(heading)
            p.resetBaseVelocity(body, [speed * c, speed * s, 0.0], physicsClientId=cid)
            for link in _WHEELS:
                p.resetJointState(body, link, 0.0, targetVelocity=speed / WHEEL_RADIUS, physicsClientId=cid)
        rolling = 0.25 * self.rolling_resistance * mass * _GRAVITY * WHEEL_RADIUS
        self._store_geometry(body, wheelbase, half_track, box_above_base, rolling, mass)
        # Coasting with centred steering until the first controls arrive.
        self.apply_controls([body], [0.0], [0.0], [0.0])
        return body

    def _store_geometry(
        self, body: int, wheelbase: float, half_track: float, above: float, rolling: float, mass: float
    ) -> None:
        if body >= len(self._wheelbase):
            size = max(2 * len(self._wheelbase), body + 1)
            for name in ("_wheelbase", "_half_track", "_box_above_base", "_rolling_torque", "_mass"):
                grown = np.zeros(size)
                old = getattr(self, name)
                grown[: len(old)] = old
                setattr(self, name, grown)
        self._wheelbase[body] = wheelbase
        self._half_track[body] = half_track
        self._box_above_base[body] = above
        self._rolling_torque[body] = rolling
        self._mass[body] = mass
        self._handles.add(body)

    def wheelbase(self, handles: Sequence[int] | np.ndarray) -> np.ndarray:
        """Axle distance of the cars, m."""
        return self._wheelbase[np.asarray(handles, dtype=np.int64)]

    def vehicle_mass(self, handles: Sequence[int] | np.ndarray) -> np.ndarray:
        """Whole-car mass of the cars, kg."""
        return self._mass[np.asarray(handles, dtype=np.int64)]

    def remove_vehicle(self, handle: int) -> None:
        if handle not in self._handles:
            raise KeyError(f"remove_vehicle: no vehicle with handle {handle} in this world")
        p.removeBody(handle, physicsClientId=self._client)
        self._handles.discard(handle)

    # ------------------------------------------------------------------ control
    def apply_controls(
        self,
        handles: Sequence[int] | np.ndarray,
        throttle: np.ndarray,
        brake: np.ndarray,
        steering: np.ndarray,
    ) -> None:
        """Set the controls held until the next call; inputs are clipped to their ranges."""
        handles = np.asarray(handles, dtype=np.int64)
        throttle = np.clip(np.asarray(throttle, dtype=np.float64), 0.0, 1.0)
        brake = np.clip(np.asarray(brake, dtype=np.float64), 0.0, 1.0)
        steering = np.clip(np.asarray(steering, dtype=np.float64), -1.0, 1.0)

        # Ackermann: each front wheel points at the common turning centre on the rear axle line.
        wheelbase, half_track = self._wheelbase[handles], self._half_track[handles]
        curvature = np.tan(steering * self.max_steer) / wheelbase
        sign, reach = np.sign(curvature), wheelbase * np.abs(curvature)
        left = sign * np.arctan2(reach, 1.0 - half_track * curvature)
        right = sign * np.arctan2(reach, 1.0 + half_track * curvature)

        net = (
            np.outer(throttle * self.max_drive_torque, _DRIVEN)
            - np.outer(brake * self.max_brake_torque, _BRAKED)
            - self._rolling_torque[handles][:, None]
        )
        target = np.where(net > 0.0, self.max_wheel_speed, 0.0)
        force = np.abs(net)
        cid = self._client
        hinge_targets = np.stack([left, right], axis=1).tolist()
        steer_forces = [self.steering_torque] * 2
        for body, tgt, frc, hinge_tgt in zip(handles.tolist(), target.tolist(), force.tolist(), hinge_targets):
            p.setJointMotorControlArray(
                body,
                _WHEELS,
                p.VELOCITY_CONTROL,
                targetVelocities=tgt,
                forces=frc,
                physicsClientId=cid,
            )
            p.setJointMotorControlArray(
                body,
                _HINGES,
                p.POSITION_CONTROL,
                targetPositions=hinge_tgt,
                forces=steer_forces,
                physicsClientId=cid,
            )

    def read_state(self, handles: Sequence[int] | np.ndarray) -> ChassisState:
        """Pose and motion of the cars, in the order of ``handles``."""
        handles = np.asarray(handles, dtype=np.int64)
        n = len(handles)
        raw = np.empty((n, 14))
        cid = self._client
        for i, body in enumerate(handles.tolist()):
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=cid)
            lin, ang = p.getBaseVelocity(body, physicsClientId=cid)
            hinge_l, hinge_r = p.getJointStates(body, _HINGES, physicsClientId=cid)
            raw[i, 0:3] = pos
            raw[i, 3:7] = quat
            raw[i, 7:9] = lin[:2]
            raw[i, 9] = ang[2]
            raw[i, 10] = hinge_l[0]
            raw[i, 11] = hinge_r[0]
        qx, qy, qz, qw = raw[:, 3], raw[:, 4], raw[:, 5], raw[:, 6]
        heading = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        # The box centre sits above the base frame along the body's up axis.
        above = self._box_above_base[handles]
        x = raw[:, 0] + above * 2.0 * (qx * qz + qw * qy)
        y = raw[:, 1] + above * 2.0 * (qy * qz - qw * qx)
        speed = raw[:, 7] * np.cos(heading) + raw[:, 8] * np.sin(heading)
        steering = 0.5 * (raw[:, 10] + raw[:, 11])
        return ChassisState(x, y, heading, speed, raw[:, 9].copy(), steering)

    def base_height(self, handle: int) -> float:
        """Height of the chassis base frame above the ground, m (for settling checks)."""
        return float(p.getBasePositionAndOrientation(handle, physicsClientId=self._client)[0][2])


def apply_continuous(
    world: PhysicsWorld,
    table: VehicleTable,
    rows: np.ndarray,
    handles: Sequence[int] | np.ndarray,
    actions: np.ndarray,
    dt: float,
) -> None:
    """Drive ``rows`` (their cars are ``handles`` in ``world``) by Continuous actions ``[n, 3]``.

    Steps the whole world once, so pass every physics-driven row of the world in one call. Writes x,
    y, heading, speed, accel, jerk, yaw_rate, lat_accel and steering of the rows in place.
    """
    if abs(dt - world.dt) > 1e-12:
        raise ValueError(f"apply_continuous: dt {dt} differs from the physics world's dt {world.dt}")
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != (len(rows), 3) or not np.isfinite(actions).all():
        ids = [str(table.ids[r]) for r in np.asarray(rows).tolist()]
        check_actions(ActionSpaceType.CONTINUOUS, actions, ids)
    world.apply_controls(handles, actions[:, 0], actions[:, 1], actions[:, 2])
    world.step()
    state = world.read_state(handles)
    table.x[rows] = state.x
    table.y[rows] = state.y
    table.heading[rows] = state.heading
    accel = (state.speed - table.speed[rows]) / dt
    table.jerk[rows] = (accel - table.accel[rows]) / dt
    table.accel[rows] = accel
    table.speed[rows] = state.speed
    table.yaw_rate[rows] = state.yaw_rate
    table.lat_accel[rows] = state.speed * state.yaw_rate
    table.steering[rows] = state.steering
