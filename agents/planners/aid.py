"""AID: a Frenet sampling planner over a motion predictor (the 2022 NTU AutoMan entry).

Every 3 steps it re-plans: for each observed lane path, a spline reference; 11 candidate
trajectories per path (longitudinal accelerations -5..5 m/s^2, a cubic speed profile to
v_T = clip(v + 3a, 0, 16) and a quintic lateral return to the path's centre); the 5 nearest
neighbours predicted 3 s ahead (constant velocity, or the learned predictor); each candidate
scored by J = d2g + 0.5 spd + 0.1 jerk + 0.1 lat + prox + 5 ttc + 10 coll (weights of the
original); the cheapest is executed for 3 steps as chained RelativeTargetPose steps. When every
candidate collides it brakes along its own lane.

Deviations (see the zoo card): s is measured from the ego's projection on each reference (the
original from the path's first point); the emergency plan brakes at the 9 m/s^2 our limits allow
(not 15) along the path the ego is on (not the last path of the loop); endless missions have
d2g = 0 for all paths; neighbour histories come from the tracker, not ids. Because our cars
cannot turn at any speed, the speed term tracks min(v_lim, sqrt(2 m/s^2 / curvature)) along the
candidate instead of v_lim, and a candidate whose speed times curvature exceeds the 1.2 rad/s yaw
rate limit costs 10 more (the original ran without dynamics limits); references are smoothed
(Gaussian, 2 points) since junction lanes here are kinked polylines, and pose headings follow the
reference (plus the lateral drift) rather than successive points.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from agents.obs_columns import GOAL_XY, NEIGHBOUR_XY, Ego, Goal, Neighbour
from agents.planners.agent_state import AgentState, StatefulPlanner
from agents.planners.frames import chain, wrap
from agents.planners.geometry import cubic_coefficients, polyval, quintic_coefficients
from agents.planners.paths import Reference, extend, project, valid_path
from agents.planners.tracker import NeighbourTracker

INTERFACE = {"waypoints": {"count": 51, "spacing": 1}, "neighbours": {"count": 8, "radius": 50.0}}
WEIGHTS = (1.0, 0.5, 0.1, 0.1, 1.0, 5.0, 10.0)
"""d2g, spd, jerk, lat, prox, ttc, coll."""
ACCELERATIONS = np.arange(-5.0, 6.0)
HORIZON = 30
DT = 0.1
MAX_SPEED = 16.0
LATERAL_RATE = 1.5
MIN_LATERAL_TIME = 1.0
REPLAN_EVERY = 3
HISTORY = 11
NEAREST = 5
EMERGENCY_DECEL = 9.0
MAX_YAW_RATE = 1.2
CURVE_LAT_ACCEL = 3.0
SMOOTH = 2.0
INFEASIBLE = 10.0
WINDOW_S, WINDOW_D, PREFILTER = 5.0, 2.5, 5.0


class AIDState(AgentState):
    def __init__(self) -> None:
        super().__init__()
        self.tracker = NeighbourTracker()
        self.queue: list[np.ndarray] = []
        self.since_plan = REPLAN_EVERY
        self.emergency = False
        self.ego_history: list[np.ndarray] = []  # odometry (x, y, heading, speed), oldest first
        self.ids = np.zeros(0, dtype=np.int64)


class Candidate:
    """One sampled trajectory: poses [T, 3] in the ego frame, Frenet samples and its path."""

    def __init__(
        self, path: int, accel: float, xy: np.ndarray, yaw: np.ndarray, s: np.ndarray, d: np.ndarray, v: np.ndarray
    ):
        self.path, self.accel = path, accel
        self.xy, self.yaw, self.s, self.d, self.v = xy, yaw, s, d, v

    @property
    def poses(self) -> np.ndarray:
        return np.column_stack([self.xy, self.yaw])


def longitudinal_profile(v_s: float, a_s: float, accel: float) -> np.ndarray:
    """Speeds [30] at t = 0, 0.1, ... of the cubic speed profile to v_T = clip(v_s + 3a, 0, 16),
    held at v_T after T and clipped to [0.01, 16]."""
    v_t = float(np.clip(v_s + 3.0 * accel, 0.0, MAX_SPEED))
    T = 3.0 if accel == 0 else float(np.clip(round((v_t - v_s) / accel, 3), 0.1, 3.0))
    c = cubic_coefficients(v_s, a_s, v_t, 0.0, T)
    t = np.arange(0.0, T - 1e-9, DT)[:HORIZON]
    v = polyval(c, t)
    v = np.concatenate([v, np.full(HORIZON - len(v), v[-1] if len(v) else v_t)])
    return np.clip(v, 0.01, MAX_SPEED)


def lateral_profile(d0: float, v_d: float) -> np.ndarray:
    """Offsets [30] at t = 0.1 .. 3.0 of the quintic from (d0, v_d, 0) to (0, 0, 0) over
    T_d = clip(|d0| / 1.5, 1.0, 3), held at 0 afterwards (the original's lower bound 0.1 s snaps
    back from small offsets faster than our yaw-rate limit allows)."""
    T = float(np.clip(abs(d0) / LATERAL_RATE, MIN_LATERAL_TIME, 3.0))
    c = quintic_coefficients(d0, v_d, 0.0, 0.0, 0.0, 0.0, T)
    t = np.arange(1, HORIZON + 1) * DT
    return np.where(t <= T + 1e-9, polyval(c, np.minimum(t, T)), 0.0)


def kinematic_costs(xy: np.ndarray, yaw: np.ndarray) -> tuple[float, float]:
    """(mean |jerk| / 10, mean |lateral acceleration| / 10) from finite differences of the samples."""
    if len(xy) < 4:
        return 0.0, 0.0
    vel = np.diff(xy, axis=0) / DT
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    v_lon = c * vel[:, 0] + s * vel[:, 1]
    v_lat = -s * vel[:, 0] + c * vel[:, 1]
    acc = np.diff(v_lon) / DT
    jerk = np.diff(acc) / DT
    lat = np.diff(v_lat) / DT
    return float(np.mean(np.abs(jerk)) / 10.0), float(np.mean(np.abs(lat)) / 10.0)


def project_predictions(ref: Reference, predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s, d, inner) [N, 30] of predicted points on a reference: the nearest 0.1 m sample, the
    signed offset from it, and whether that sample is neither the first nor the last."""
    flat = predicted.reshape(-1, 2)
    k = np.argmin(((flat[:, None, :] - ref.xy[None]) ** 2).sum(-1), axis=1)
    normal = np.stack([-np.sin(ref.yaw[k]), np.cos(ref.yaw[k])], axis=1)
    shape = predicted.shape[:2]
    d_nb = ((flat - ref.xy[k]) * normal).sum(1).reshape(shape)
    return (ref.step * k).reshape(shape), d_nb, ((k > 0) & (k < len(ref.s) - 1)).reshape(shape)


def interaction_costs(cand: Candidate, ref: Reference, predicted: np.ndarray,
                      projected: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> tuple[float, float, float]:  # fmt: skip
    """(prox, ttc, coll) of a candidate against predicted neighbour points [N, 30, 2]: a fixed
    5 m x 2.5 m Frenet window along the candidate's reference, a 5 m Euclidean prefilter.
    ``projected``: :func:`project_predictions` of the reference, shared by its candidates."""
    if len(predicted) == 0:
        return float(np.exp(-0.3 * min(100.0 - 3.0, 20.0) ** 2)), 0.0, 0.0
    T = len(cand.xy)
    pts = predicted[:, :T]  # [N, T, 2]
    near = np.linalg.norm(pts - cand.xy[None], axis=2) <= PREFILTER  # [N, T]
    s_nb, d_nb, inner = projected if projected is not None else project_predictions(ref, predicted)
    s_nb, d_nb, inner = s_nb[:, :T], d_nb[:, :T], inner[:, :T]
    ds = np.abs(cand.s[None, :T] - s_nb)
    dd = np.abs(cand.d[None, :T] - d_nb)
    checked = near & inner
    lateral = checked & (dd < WINDOW_D)
    hit = (lateral & (ds < WINDOW_S)).any(axis=0)  # [T]
    dist = np.linalg.norm(pts - cand.xy[None], axis=2)
    if hit.any():
        first = int(np.argmax(hit))
        ttc_time = (first + 1) * DT
        dist_seen = np.where(lateral[:, : first + 1], dist[:, : first + 1], np.inf)
        coll = 1.0
    else:
        ttc_time = 3.0
        dist_seen = np.where(lateral, dist, np.inf)
        coll = 0.0
    min_dist = min(100.0, float(dist_seen.min())) if dist_seen.size else 100.0
    prox = float(np.exp(-0.3 * np.clip(min_dist - 3.0, 0.0, 20.0) ** 2))
    return prox, 1.0 - ttc_time / 3.0, coll


class ConstantVelocity:
    """The CV predictor: every neighbour keeps its current velocity for 3 s."""

    def __call__(self, state: AIDState, row: dict[str, np.ndarray], picked: np.ndarray) -> np.ndarray:
        nb = row["neighbours"][picked].astype(np.float64)
        vel = np.stack([nb[:, Neighbour.VX] + float(row["ego"][Ego.SPEED]), nb[:, Neighbour.VY]], axis=1)
        t = np.arange(1, HORIZON + 1) * DT
        return nb[:, None, NEIGHBOUR_XY] + vel[:, None, :] * t[None, :, None]


def in_frame(states: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Odometry states [..., >=4] (x, y, heading, speed) -> predictor features (x, y, relative
    heading, vx, vy) in the frame of ``pose``; all-zero rows (unseen) stay zero."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = states[..., 0] - pose[0], states[..., 1] - pose[1]
    rel = wrap(states[..., 2] - pose[2])
    v = states[..., 3]
    out = np.stack([c * dx + s * dy, -s * dx + c * dy, rel, v * np.cos(rel), v * np.sin(rel)], axis=-1)
    return np.where((np.abs(states[..., :4]).sum(-1) > 0)[..., None], out, 0.0)


class LearnedPredictor:
    """AID's learned predictor: 11-step histories of the ego (odometry) and of the picked
    neighbours (tracker), in the current ego frame -> the highest-scored of 3 modes."""

    def __init__(self, path):
        import torch

        from agents.planners.nets import load_net

        self.torch = torch
        self.net, self.metrics = load_net(path, "aid-predictor")
        self.path = str(path)

    def __call__(self, state: AIDState, row: dict[str, np.ndarray], picked: np.ndarray) -> np.ndarray:
        torch = self.torch
        pose = state.odometry.pose
        ego = np.zeros((HISTORY, 4))
        hist = np.array(state.ego_history)
        ego[HISTORY - len(hist) :] = hist
        nb = np.zeros((5, HISTORY, 4))
        for j, r in enumerate(picked[:5]):
            nb[j] = state.tracker.history(int(state.ids[r]), HISTORY)[:, :4]
        with torch.no_grad():
            trajs, scores = self.net(torch.as_tensor(in_frame(ego, pose)[None], dtype=torch.float32),
                                     torch.as_tensor(in_frame(nb, pose)[None], dtype=torch.float32))  # fmt: skip
        best = scores[0].argmax(-1)  # [5]
        out = trajs[0, torch.arange(5), best, :, :2].numpy().astype(np.float64)
        return out[: len(picked)]


class AIDPlanner(StatefulPlanner):
    """Frenet sampling over lane paths x 11 accelerations; ``predictor`` maps (state, row, picked
    neighbour rows) to predicted ego-frame points [N, 30, 2]."""

    interface = INTERFACE

    def __init__(self, predictor: Callable[..., np.ndarray] | None = None):
        super().__init__()
        self.predictor = predictor or ConstantVelocity()
        self.last_candidates: list[Candidate] = []
        self.last_costs = np.zeros(0)

    def new_state(self) -> AIDState:
        return AIDState()

    def decide(self, state: AIDState, row: dict[str, np.ndarray]) -> np.ndarray:
        ego = row["ego"]
        speed = float(ego[Ego.SPEED])
        state.ids = state.tracker.update(state.odometry.pose, speed, row["neighbours"], row["neighbour_mask"])
        state.ego_history = (state.ego_history + [np.array([*state.odometry.pose, speed])])[-HISTORY:]
        if state.queue and state.since_plan < REPLAN_EVERY:
            state.since_plan += 1
            return state.queue.pop(0)
        poses = self.plan(state, row)
        if poses is None:  # no usable lane path: keep heading, brake gently
            v = max(speed - 2.0 * DT, 0.0)
            return np.array([v * DT, 0.0, 0.0])
        state.queue = list(chain(poses))
        state.since_plan = 1
        return state.queue.pop(0)

    def references(self, row: dict[str, np.ndarray]) -> list[tuple[int, Reference]]:
        refs = []
        for p in range(row["waypoints"].shape[0]):
            pts = valid_path(row["waypoints"][p], row["waypoint_mask"][p])
            if len(pts) < 2:
                continue
            first = pts[0]  # one point 2 m behind, so the ego projects inside the reference
            back = np.array([first[0] - 2.0 * np.cos(first[2]), first[1] - 2.0 * np.sin(first[2]), first[2]])
            refs.append((p, Reference(np.vstack([back, extend(pts, 51)]), smooth=SMOOTH)))
        return refs

    def plan(self, state: AIDState, row: dict[str, np.ndarray]) -> np.ndarray | None:
        """The chosen trajectory's 30 poses (ego frame), or None without lane paths."""
        ego, goal = row["ego"].astype(np.float64), row["goal"].astype(np.float64)
        refs = self.references(row)
        if not refs:
            return None
        speed, accel = float(ego[Ego.SPEED]), float(ego[Ego.ACCEL])
        v_lim = max(float(ego[Ego.SPEED_LIMIT]), 1.0)
        has_goal = goal[Goal.HAS_GOAL] > 0
        goal_dist = [float(np.min(np.linalg.norm(ref.xy - goal[GOAL_XY], axis=1))) for _, ref in refs]
        best_goal = min(goal_dist)
        predicted = self.predict(state, row)
        candidates, costs, refs_of = [], [], []
        own = min(range(len(refs)), key=lambda i: abs(project(refs[i][1].xy, np.zeros((1, 2)))[1][0]))
        for i, (p, ref) in enumerate(refs):
            s_ego, d_ego = project(ref.xy, np.zeros((1, 2)))
            theta0 = float(ref.yaw[min(int(max(s_ego[0], 0.0) / ref.step), len(ref.yaw) - 1)])
            v_s, v_d = speed * np.cos(theta0), -speed * np.sin(theta0)
            a_s = accel * np.cos(theta0)
            d0 = float(d_ego[0])  # the ego's offset to the left of the path
            d = lateral_profile(d0, v_d)
            d2g = (goal_dist[i] - best_goal) if has_goal else 0.0
            projected = project_predictions(ref, predicted) if len(predicted) else None
            for a in ACCELERATIONS:
                v = longitudinal_profile(v_s, a_s, float(a))
                s = max(float(s_ego[0]), 0.0) + np.cumsum(DT * v)
                xy, yaw, valid = ref.frenet_to_xy(s, d)
                n = int(np.argmin(valid)) if not valid.all() else len(valid)
                if n < 2:
                    continue
                # heading: the reference's plus the lateral drift (successive points are noisy at low speed)
                yaw = wrap(yaw + np.arctan2(np.gradient(d, s) if len(s) > 1 else 0.0, 1.0))
                cand = Candidate(p, float(a), xy[:n], yaw[:n], s[:n], d[:n], v[:n])
                jerk, lat = kinematic_costs(cand.xy, cand.yaw)
                # the speed target slows for curves (our limits: yaw rate, no instant turns)
                kappa = np.abs(np.interp(s[:n], ref.s, ref.curvature))
                target = np.minimum(v_lim, np.sqrt(CURVE_LAT_ACCEL / np.maximum(kappa, 1e-6)))
                spd = float(np.mean(np.abs(v[:n] - target) / v_lim))
                infeasible = float((v[:n] * kappa > MAX_YAW_RATE).any())
                prox, ttc, coll = interaction_costs(cand, ref, predicted, projected)
                terms = np.array([d2g, spd, jerk, lat, prox, ttc, coll])
                candidates.append(cand)
                refs_of.append(ref)
                costs.append(float(np.dot(WEIGHTS, terms)) + INFEASIBLE * infeasible)
                cand.terms = terms  # type: ignore[attr-defined]
        self.last_candidates, self.last_costs = candidates, np.array(costs)
        if not candidates:
            return None
        colliding = np.array([c.terms[6] > 0 for c in candidates])  # type: ignore[attr-defined]
        state.emergency = bool(colliding.all())
        if state.emergency:
            return self.emergency(refs[own][1], speed)
        return candidates[int(np.argmin(costs))].poses

    def emergency(self, ref: Reference, speed: float) -> np.ndarray:
        """Brake at the limit along the path the ego is on, holding the ego's offset."""
        s_ego, d_ego = project(ref.xy, np.zeros((1, 2)))
        t = np.arange(HORIZON) * DT
        v = np.clip(speed - EMERGENCY_DECEL * (t + DT), 0.0, MAX_SPEED)
        s = max(float(s_ego[0]), 0.0) + np.cumsum(DT * v)
        xy, yaw, valid = ref.frenet_to_xy(s, np.full(HORIZON, float(d_ego[0])))
        n = max(int(np.argmin(valid)) if not valid.all() else len(valid), 1)
        return np.column_stack([xy[:n], yaw[:n]])

    def predict(self, state: AIDState, row: dict[str, np.ndarray]) -> np.ndarray:
        """Predicted points [N, 30, 2] (ego frame) of the 5 nearest neighbours."""
        mask = row["neighbour_mask"] > 0
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            return np.zeros((0, HORIZON, 2))
        dist = np.hypot(row["neighbours"][idx, Neighbour.DX], row["neighbours"][idx, Neighbour.DY])
        picked = idx[np.argsort(dist, kind="stable")[:NEAREST]]
        return np.asarray(self.predictor(state, row, picked), dtype=np.float64)
