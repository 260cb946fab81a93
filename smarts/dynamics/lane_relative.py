"""Lane-relative commands for learning: (speed, lane change) turned into real actions.

Why: a policy that outputs raw (dx, dy, dheading) or (throttle, brake, steering) must first learn
to stay on the road, and its zero action (what an untrained Gaussian policy outputs) asks to stop
or to coast. Here the zero command is a sane one: keep the current speed in the current lane.
The command is then turned into the agent's own action space (RelativeTargetPose, TargetPose or
Continuous), so the vehicle obeys exactly the limits and physics of that space and a benchmark
run in that space stays honest. Nothing here decides *what* to do (no car following, no gap
keeping): the policy chooses every target speed and every lane change; this module only tracks
them, like a driver's feet and hands follow the driver's decisions.

Command (float ``[n, 2]``, each component in [-1, 1]; values outside are clipped):

- ``speed``: the target speed, relative to the speed limit of the lane followed:
  ``limit * (1 + speed)``, so 0 cruises at the limit, -1 stops and +1 asks for twice the limit.
  The acceleration towards it is ``(target - v) / speed_time_constant``, at most ``max_accel``
  and ``max_decel``, and changes at most at ``max_jerk`` (m/s^3), so the ride is smooth; only a
  demand to brake harder than ``comfort_decel`` may build up braking faster (``brake_jerk``). (A
  target rather than an acceleration: the mean command sets where the speed settles, which a
  policy learns far faster than the integral of noisy accelerations.)
- ``lane_change``: above ``+threshold`` change one lane to the left, below ``-threshold`` one to the
  right, otherwise keep the lane. A change runs to its end (``lane_change_time`` seconds along a
  smooth lateral profile) before another one starts. Where the road has no lane on the asked side,
  the request is kept as the branch to take at the next fork or junction (the continuation next
  to the left or right of the default one) until the vehicle has passed that fork.

Which lane is followed: the vehicle's current lane (or, during a change, its neighbour), continued
through successor lanes; at a fork the default continuation is the one on the agent's own route,
else the straightest, and a remembered branch request takes its neighbour to the left or right. The vehicle steers by pure
pursuit to the point ``max(speed * lookahead_time, min_lookahead)`` metres ahead on that lane,
shifted sideways by what remains of the lane-change profile.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.core.geometry import wrap_scalar
from smarts.core.sim_records import lanes_record
from smarts.core.spec.lane_relative import LaneRelativeParams
from smarts.core.vehicle_table import COLUMN
from smarts.records import declare, freeze_fields, view

COMMAND_COMPONENTS = ("speed", "lane_change")
DEFAULT_SPEED_LIMIT = 13.89
"""m/s used off the map, where no lane gives a limit."""
U_TURN = 2.6
"""rad: continuations turning more than this are U-turns, taken only when the route says so."""


class Limits(NamedTuple):
    """``LaneRelativeParams`` as the kernel reads them (same names)."""

    speed_time_constant: float
    max_accel: float
    max_decel: float
    max_jerk: float
    brake_jerk: float
    comfort_decel: float
    lane_change_time: float
    lookahead_time: float
    min_lookahead: float
    threshold: float


class ControllerState(NamedTuple):
    """A controller's limits and per-agent state (its own arrays, kept between steps)."""

    limits: Limits
    route_road: np.ndarray  # bool[A, R] roads on each agent's route
    track: np.ndarray  # int64[A] the lane being followed, -1 none
    track_s: np.ndarray  # float64[A] where on it at the last step
    pending: np.ndarray  # int64[A] lane change under way: -1 right, +1 left, 0 none
    profile_start: np.ndarray  # float64[A] lateral offset to the target lane when it began
    profile_age: np.ndarray  # float64[A] s since the profile began
    branch: np.ndarray  # int64[A] remembered fork choice


declare(ControllerState)


@njit(nogil=True)
def _freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


class LaneRelativeController:
    """Per-agent lane-change state and the command -> target conversion for one simulation.

    Agent-indexed state (``n_agents`` entries) survives between steps and is cleared by ``reset``.
    """

    def __init__(self, n_agents: int, params: LaneRelativeParams | None = None):
        self.params = params or LaneRelativeParams()
        self.n = n_agents
        self.track = np.full(n_agents, -1, dtype=np.int64)  # the lane being followed
        self.track_s = np.zeros(n_agents)  # where on it at the last step (the next search's hint)
        self.pending = np.zeros(n_agents, dtype=np.int64)  # -1 right, +1 left, 0 none
        self.profile_start = np.zeros(n_agents)  # lateral offset to the target lane when it began
        self.profile_age = np.full(n_agents, np.inf)  # s since the profile began
        self.branch = np.zeros(n_agents, dtype=np.int64)  # remembered fork choice
        self._route_road: np.ndarray | None = None
        self._state = None  # frozen ControllerState, made at the first ``targets``

    def reset(self, sim) -> None:
        self.reset_agents(sim, np.arange(self.n))

    def reset_agents(self, sim, agents: np.ndarray) -> None:
        """Clear the state of ``agents`` (a new episode of theirs begins)."""
        self.track[agents] = -1
        self.pending[agents] = 0
        self.profile_start[agents] = 0.0
        self.profile_age[agents] = np.inf
        self.branch[agents] = 0
        if self._route_road is None:
            self._route_road = np.ascontiguousarray(sim.mission_arrays.on_route_road)

    def targets(self, sim, members: np.ndarray, rows: np.ndarray, commands: np.ndarray, dt: float):
        """Advance the state of agents ``members`` (rows ``rows``) by one step of ``commands``.

        Returns ``(accel, curvature, target_x, target_y)``: the acceleration (m/s^2) towards the
        target speed,
        the pure-pursuit path curvature (1/m) and the pursued point (world frame) per member.
        """
        if self._route_road is None:
            self.reset(sim)
        if self._state is None:
            self._state = _freeze(ControllerState(
                limits=Limits(**{k: float(v) for k, v in asdict(self.params).items()}), route_road=self._route_road,
                track=self.track, track_s=self.track_s, pending=self.pending, profile_start=self.profile_start,
                profile_age=self.profile_age, branch=self.branch,
            ))  # fmt: skip
        cmd = np.clip(np.asarray(commands, dtype=np.float64), -1.0, 1.0)
        n = len(members)
        accel, curvature, target = np.empty(n), np.empty(n), np.empty((n, 2))
        _targets_kernel(
            lanes_record(sim.road_map), self._state, sim.table.data, sim.table.lane, np.asarray(members, np.int64),
            np.asarray(rows, np.int64), cmd, dt, accel, curvature, target,
        )  # fmt: skip
        return accel, curvature, target[:, 0], target[:, 1]

    # ------------------------------------------------------------------ conversions
    def relative_pose_actions(self, sim, members, rows, commands, dt: float) -> np.ndarray:
        """RelativeTargetPose actions ``[n, 3]``: an arc of the pursued curvature at the new speed.

        The pose limiter of RelativeTargetPose still applies afterwards (speed, yaw rate, curvature).
        """
        accel, kappa, _, _ = self.targets(sim, members, rows, commands, dt)
        speed = np.maximum(sim.table.speed[rows], 0.0)
        new_speed = np.maximum(speed + accel * dt, 0.0)
        d = new_speed * dt
        dh = kappa * d
        return np.stack([d * np.cos(0.5 * dh), d * np.sin(0.5 * dh), dh], axis=1)

    def target_pose_actions(self, sim, members, rows, commands, dt: float) -> np.ndarray:
        """TargetPose actions ``[n, 3]``: the relative pose expressed in the world frame."""
        rel = self.relative_pose_actions(sim, members, rows, commands, dt)
        t = sim.table
        h = t.heading[rows]
        c, s = np.cos(h), np.sin(h)
        x = t.x[rows] + c * rel[:, 0] - s * rel[:, 1]
        y = t.y[rows] + s * rel[:, 0] + c * rel[:, 1]
        heading = np.arctan2(np.sin(h + rel[:, 2]), np.cos(h + rel[:, 2]))
        return np.stack([x, y, heading], axis=1)

    def continuous_actions(self, sim, members, rows, commands, dt: float, world, mass, wheelbase) -> np.ndarray:
        """Continuous actions ``[n, 3]`` (throttle, brake, steering) for pybullet cars.

        Throttle and brake come from the car's torque model (the force that gives the asked
        acceleration, plus rolling resistance) and steering from the pursued curvature through the
        car's wheelbase; the physics decides what actually happens. ``world`` gives the car
        model's constants, ``mass`` and ``wheelbase`` each car's.
        """
        accel, kappa, _, _ = self.targets(sim, members, rows, commands, dt)
        from smarts.dynamics.pybullet_chassis import WHEEL_RADIUS

        rolling = world.rolling_resistance * 9.81
        drive = np.clip(mass * (accel + rolling) * WHEEL_RADIUS / world.max_drive_torque, 0.0, 1.0)
        brake = np.clip(mass * np.maximum(-accel - rolling, 0.0) * WHEEL_RADIUS / world.max_brake_torque, 0.0, 1.0)
        drive = np.where(accel + rolling > 0.0, drive, 0.0)
        steering = np.clip(np.arctan(kappa * wheelbase) / world.max_steer, -1.0, 1.0)
        return np.stack([drive, brake, steering], axis=1)


@njit(nogil=True)
def _smooth(u):  # pragma: no cover - compiled
    """Quintic smoothstep on [0, 1]: zero velocity and acceleration at both ends."""
    if u <= 0.0:
        return 0.0
    if u >= 1.0:
        return 1.0
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


@njit(nogil=True)
def _point_on_lane(offsets, points, point_s, heading, lane, s):  # pragma: no cover - compiled
    a, b = offsets[lane], offsets[lane + 1]
    if b - a == 1:
        return points[a, 0], points[a, 1], heading[a]
    lo, hi = a, b - 1
    if s <= point_s[a]:
        k = a
    elif s >= point_s[b - 1]:
        k = b - 2
    else:
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if point_s[mid] <= s:
                lo = mid
            else:
                hi = mid
        k = lo
    seg = max(point_s[k + 1] - point_s[k], 1e-9)
    u = (s - point_s[k]) / seg
    x = points[k, 0] + u * (points[k + 1, 0] - points[k, 0])
    y = points[k, 1] + u * (points[k + 1, 1] - points[k, 1])
    return x, y, heading[k] if u < 0.5 else heading[k + 1]


@njit(nogil=True)
def _turn_of(lanes, lane, nxt):  # pragma: no cover - compiled
    """Heading change from the end of ``lane`` through the junction that ``nxt`` enters (rad, +
    left): junction lanes with a single successor are followed to the lane leaving the junction."""
    offsets, heading = lanes.point_offsets, lanes.point_heading
    succ_offsets, succ, internal = lanes.succ_offsets, lanes.succ, lanes.internal
    end = heading[offsets[lane + 1] - 1]
    cur = nxt
    guard = 0
    while internal[cur] and succ_offsets[cur + 1] - succ_offsets[cur] == 1 and guard < 8:
        following = succ[succ_offsets[cur]]
        if not internal[following]:
            break
        cur = following
        guard += 1
    if internal[cur] and succ_offsets[cur + 1] - succ_offsets[cur] == 1:  # the lane leaving the junction
        return wrap_scalar(heading[offsets[succ[succ_offsets[cur]]]] - end)
    return wrap_scalar(heading[offsets[cur + 1] - 1] - end)


@njit(nogil=True)
def _next_lane(lanes, route_road, lane, branch, agent):  # pragma: no cover - compiled
    """The successor to follow at the end of ``lane``: the default one (on the agent's route, else
    the straightest), or with a branch request the next one to its left (+1) or right (-1)."""
    succ_offsets, succ, lane_road = lanes.succ_offsets, lanes.succ, lanes.road
    a, b = succ_offsets[lane], succ_offsets[lane + 1]
    if b == a:
        return -1
    if b - a == 1:
        return succ[a]
    default, default_key = succ[a], np.inf
    for k in range(a, b):
        nxt = succ[k]
        turn = _turn_of(lanes, lane, nxt)
        key = abs(turn) + (0.0 if route_road[agent, lane_road[nxt]] else 100.0)
        if key < default_key:
            default, default_key = nxt, key
    if branch == 0:
        return default
    base = _turn_of(lanes, lane, default)
    best, best_gap = default, np.inf
    for k in range(a, b):
        nxt = succ[k]
        turn = _turn_of(lanes, lane, nxt)
        gap = (turn - base) * branch
        if abs(turn) < U_TURN and 1e-3 < gap < best_gap:  # a U-turn is never a branch request
            best, best_gap = nxt, gap
    return best


@njit(nogil=True)
def _accel(limits, command, limit, v, previous, dt):  # pragma: no cover - compiled
    """Towards the target speed ``limit * (1 + command)``, within the acceleration and jerk limits
    (``limits``, a ``Limits``)."""
    tau, max_accel, max_decel = limits.speed_time_constant, limits.max_accel, limits.max_decel
    max_jerk, brake_jerk, comfort_decel = limits.max_jerk, limits.brake_jerk, limits.comfort_decel
    target = max(limit, 0.1) * (1.0 + command)
    want = min(max((target - v) / tau, -max_decel), max_accel)
    if target < 0.05 and v < 0.01:  # the last centimetre per second: come to rest
        want = -v / dt
    down = brake_jerk if want < -comfort_decel else max_jerk
    accel = min(max(want, previous - down * dt), previous + max_jerk * dt)
    # Ease off the brake while stopping, so the car halts without a jolt: once releasing the brake
    # at max_jerk would take all the speed that is left, release it.
    deepest = min(accel, previous)
    if deepest < 0.0 and v + deepest * dt <= deepest * deepest / (2.0 * max_jerk) + 1e-9:
        accel = max(accel, min(previous + max_jerk * dt, 0.0))
    return accel


@njit(nogil=True)
def _nearest_segment(offsets, points, point_s, lane, x, y, lo, hi):  # pragma: no cover - compiled
    """(d2, s, t, k) of the nearest of segments ``lo..hi`` of one lane to a point (t + left); the
    lane's first and last segments extend past its ends, so s keeps growing there."""
    a, last = offsets[lane], offsets[lane + 1] - 2
    best_d2, best_s, best_t, best_k = np.inf, 0.0, 0.0, lo
    for k in range(lo, hi + 1):
        vx, vy = points[k + 1, 0] - points[k, 0], points[k + 1, 1] - points[k, 1]
        rx, ry = x - points[k, 0], y - points[k, 1]
        len2 = vx * vx + vy * vy
        if len2 <= 0.0:
            continue
        raw = (rx * vx + ry * vy) / len2
        u = min(max(raw, 0.0), 1.0)
        if (k == a and raw < 0.0) or (k == last and raw > 1.0):
            u = raw
        dx, dy = rx - u * vx, ry - u * vy
        d2 = dx * dx + dy * dy
        if d2 < best_d2:
            best_d2, best_k = d2, k
            best_s = point_s[k] + u * math.sqrt(len2)
            best_t = math.sqrt(d2) if vx * ry - vy * rx >= 0.0 else -math.sqrt(d2)
    return best_d2, best_s, best_t, best_k


@njit(nogil=True)
def _project_on_lane(offsets, points, point_s, lane, x, y):  # pragma: no cover - compiled
    """(s, t) of a point on one lane's centre line (t + left); s runs on past both ends."""
    a, b = offsets[lane], offsets[lane + 1]
    if b - a < 2:
        return 0.0, 0.0
    _, s, t, _ = _nearest_segment(offsets, points, point_s, lane, x, y, a, b - 2)
    return s, t


PROJECTION_WINDOW = 8
"""Segments searched on each side of the hinted one before the whole lane is scanned."""


@njit(nogil=True)
def _project_near(offsets, points, point_s, lane, x, y, s_hint):  # pragma: no cover - compiled
    """``_project_on_lane`` searched near arc length ``s_hint`` (where the car was, or where it
    is on a parallel lane): ``PROJECTION_WINDOW`` segments either side, and the whole lane when
    the nearest one lies on the window's edge (the hint was off). Lanes are sampled every metre,
    so a full scan costs a few hundred segments per call; this costs about 17."""
    a, b = offsets[lane], offsets[lane + 1]
    last = b - 2  # the last segment
    if last - a <= 2 * PROJECTION_WINDOW + 1:
        return _project_on_lane(offsets, points, point_s, lane, x, y)
    k0 = a + np.searchsorted(point_s[a:b], s_hint) - 1
    k0 = min(max(k0, a), last)
    lo, hi = max(a, k0 - PROJECTION_WINDOW), min(last, k0 + PROJECTION_WINDOW)
    _, s, t, k = _nearest_segment(offsets, points, point_s, lane, x, y, lo, hi)
    if (k == lo and lo > a) or (k == hi and hi < last):
        return _project_on_lane(offsets, points, point_s, lane, x, y)
    return s, t


@njit(nogil=True)
def _targets_kernel(
    frozen_lanes,
    frozen_state,
    data,
    lane_col,
    members,
    rows,
    cmd,
    dt,
    accel_out,
    kappa_out,
    target_out,
):  # pragma: no cover - compiled
    """``LaneRelativeController.targets``: members ``members`` on rows ``rows`` follow ``cmd``
    (``frozen_lanes``: the map's frozen ``Lanes``; ``frozen_state``: the controller's frozen
    ``ControllerState``, updated here) into their acceleration, pure-pursuit curvature and pursued
    point (x, y). The outputs are plain arrays: a call types each argument, and a tuple of them
    would cost about 1 us more per call to type than the arrays (numba 0.68), as much as the
    kernel's work at one agent.

    Stays whole: split into ``@njit`` helpers (lane tracking, change arrival, pursued point,
    curvature), inlined or not, taking the views or plain arrays, it took 1.6-1.8x the CPU time
    (30 agents: about 25 -> 40-47 us per step)."""
    lanes, state = view(frozen_lanes), view(frozen_state)
    limits = state.limits
    lc_time, look_time, min_look, threshold = (
        limits.lane_change_time,
        limits.lookahead_time,
        limits.min_lookahead,
        limits.threshold,
    )
    lane_left, lane_right, lane_width, lane_length, speed_limit = (
        lanes.left,
        lanes.right,
        lanes.width,
        lanes.length,
        lanes.speed_limit,
    )
    succ_offsets = lanes.succ_offsets
    lp_offsets, lp_points, lp_s, lp_heading = lanes.point_offsets, lanes.points, lanes.point_s, lanes.point_heading
    route_road, track, track_s, pending = state.route_road, state.track, state.track_s, state.pending
    profile_start, profile_age, branch = state.profile_start, state.profile_age, state.branch
    for i in range(members.shape[0]):
        a, r = members[i], rows[i]
        x, y, h, v = data[_X, r], data[_Y, r], data[_H, r], max(data[_SPEED, r], 0.0)
        profile_age[a] += dt

        # The lane being followed: kept by this controller (where junction lanes overlap, the map
        # projection alone cannot tell which branch the car is taking), moved on to the chosen
        # successor at its end, re-taken from the projection if the car has strayed from it.
        lane = track[a]
        if lane >= 0:
            s, t = _project_near(lp_offsets, lp_points, lp_s, lane, x, y, track_s[a] + v * dt)
            guard = 0
            while s > lane_length[lane] and guard < 16:
                nxt = _next_lane(lanes, route_road, lane, branch[a], a)
                if nxt < 0:
                    break
                if succ_offsets[lane + 1] - succ_offsets[lane] > 1:
                    branch[a] = 0  # the fork is behind us
                s_next = s - lane_length[lane]
                lane = nxt
                s, t = _project_near(lp_offsets, lp_points, lp_s, lane, x, y, s_next)
                guard += 1
            if abs(t) > 0.5 * lane_width[lane] + 2.0:
                lane = -1
        if lane < 0:
            lane = lane_col[r]
            pending[a] = 0
            if lane < 0:  # off every lane: hold the wheel straight
                track[a] = -1
                kappa_out[i] = 0.0
                target_out[i, 0], target_out[i, 1] = x + math.cos(h), y + math.sin(h)
                accel_out[i] = _accel(limits, cmd[i, 0], DEFAULT_SPEED_LIMIT, v, data[_ACCEL, r], dt)
                continue
            s, t = _project_near(lp_offsets, lp_points, lp_s, lane, x, y, data[_S, r])
            if abs(t) > 0.1:  # settle onto this lane's centre smoothly
                profile_start[a] = t
                profile_age[a] = 0.0
        if pending[a] != 0:
            neighbour = lane_left[lane] if pending[a] > 0 else lane_right[lane]
            if neighbour < 0:  # the neighbour ended: settle back into this lane from where we are
                pending[a] = 0
                profile_start[a] = t
                profile_age[a] = 0.0
            else:
                sn, tn = _project_near(lp_offsets, lp_points, lp_s, neighbour, x, y, s)
                if abs(tn) < abs(t):  # over the lane line: the change has arrived
                    lane, s, t = neighbour, sn, tn
                    pending[a] = 0
        track[a] = lane
        track_s[a] = s
        accel_out[i] = _accel(limits, cmd[i, 0], speed_limit[lane], v, data[_ACCEL, r], dt)

        # A new lane-change request, once the last change is over.
        side = 1 if cmd[i, 1] > threshold else (-1 if cmd[i, 1] < -threshold else 0)
        if side != 0 and pending[a] == 0 and profile_age[a] >= lc_time:
            neighbour = lane_left[lane] if side > 0 else lane_right[lane]
            if neighbour >= 0:
                pending[a] = side
                profile_start[a] = _project_near(lp_offsets, lp_points, lp_s, neighbour, x, y, s)[1]
                profile_age[a] = 0.0
            else:
                branch[a] = side
        ref, s_ref = lane, s
        if pending[a] != 0:
            ref = lane_left[lane] if pending[a] > 0 else lane_right[lane]
            s_ref = _project_near(lp_offsets, lp_points, lp_s, ref, x, y, s)[0]
        offset = profile_start[a] * (1.0 - _smooth(profile_age[a] / lc_time))

        # The pursued point: lookahead metres along ref and its continuation, shifted by offset.
        pos = s_ref + max(v * look_time, min_look)
        cur = ref
        guard = 0
        while pos > lane_length[cur] and guard < 64:
            nxt = _next_lane(lanes, route_road, cur, branch[a], a)
            if nxt < 0:
                break
            pos -= lane_length[cur]
            cur = nxt
            guard += 1
        px, py, ph = _point_on_lane(lp_offsets, lp_points, lp_s, lp_heading, cur, pos)
        px -= math.sin(ph) * offset
        py += math.cos(ph) * offset
        target_out[i, 0], target_out[i, 1] = px, py
        c, sn = math.cos(h), math.sin(h)
        tx, ty = c * (px - x) + sn * (py - y), c * (py - y) - sn * (px - x)
        d2 = tx * tx + ty * ty
        kappa_out[i] = 2.0 * ty / d2 if d2 > 1e-6 else 0.0


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_SPEED, _ACCEL, _S, _T = COLUMN["speed"], COLUMN["accel"], COLUMN["s"], COLUMN["t"]
