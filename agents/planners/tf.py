"""TF: hierarchical driving rules with a stop/move veto (the 2022 tjudrllab-fanta entry).

Each step: situation flags (turning, density, straight road, changing lane), a meta controller
that decides stop or move (a rule forecast of an alert box in front of the ego with a hold /
ignore state machine, and optionally a behaviour-cloned stop/move network with an anti-deadlock
window), then a scheduler: leader-limited lane speeds, a lane-change utility argmax, a target
waypoint and a speed. "Stop" is the zero relative step (a brake at up to 9 m/s^2 here, not the
original's instant stop).

Deviations (see cards/tf.md): the lanes are the three observed paths; the goal lane is the route
path (0); an agent off the route path is pulled back to it (the original relied on lane ids and
goal-lane search); the 2022 merge, all-wrong-lanes and lane-end escapes and the multi-agent
right-of-way are dropped (no lane or agent ids); the alert box's front length adds the braking
distance v^2 / (2 * 9 m/s^2), because stops are not instant here, and for the same reason the
model's anti-deadlock counts only stop votes cast while standing; the network's "outcome" input
is the first 5 target-path waypoints at training time too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from agents.obs_columns import NEIGHBOUR_XY, Ego, Goal, Neighbour, WaypointPath
from agents.planners.agent_state import AgentState, StatefulPlanner
from agents.planners.frames import wrap
from agents.planners.geometry import collision_forecast
from agents.planners.lanes import LaneView, lane_view
from agents.planners.tracker import NeighbourTracker

INTERFACE = {"waypoints": {"count": 20, "spacing": 1}, "neighbours": {"count": 10, "radius": 50.0}}
NOVICE_STEPS = 15
HOLD_STEPS = 49
IGNORE_STEPS = 10
DEADLOCK_STOPS = 10
STANDING = 0.1
"""m/s below which a model stop counts towards the anti-deadlock window."""
REAR_CONE = np.deg2rad(150.0)
HEADING_CLIP = np.deg2rad(10.0)
BRAKE = 9.0
FEATURES = 53


class TFState(AgentState):
    def __init__(self) -> None:
        super().__init__()
        self.tracker = NeighbourTracker()
        self.novice = NOVICE_STEPS
        self.distance = 0.0
        self.static_cnt = 0
        self.hold = 0
        self.ignore = 0
        self.blockers: list[int] = []
        self.model_stops = 0
        self.model_ignore = 0
        self.straight_cnt = 0
        self.final_straight_cnt = 0
        self.target: int | None = None
        self.stopped_by = ""  # why the last step stopped: rule | model | ""


def neighbour_kinematics(row: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rows present, heading, speed, ego-frame velocity) of the observed neighbours."""
    nb = row["neighbours"].astype(np.float64)
    present = np.flatnonzero(row["neighbour_mask"] > 0)
    heading = np.arctan2(nb[:, Neighbour.SIN_HEADING], nb[:, Neighbour.COS_HEADING])
    vel = np.stack([nb[:, Neighbour.VX] + float(row["ego"][Ego.SPEED]), nb[:, Neighbour.VY]], axis=1)
    return present, heading, np.linalg.norm(vel, axis=1), vel


def stop_move_features(row: dict[str, np.ndarray], target_points: np.ndarray) -> np.ndarray:
    """TF's 53 numbers, in its frame (x' right, y' forward): 5 nearest on-lane neighbours x
    (x', y', vx', vy', relative heading, length, width), 5 target-path points (x', y'
    interleaved, then their headings), lane speed limit, ego length and width."""
    ego = row["ego"].astype(np.float64)
    out = np.zeros(FEATURES, dtype=np.float32)
    present, heading, _, vel = neighbour_kinematics(row)
    nb = row["neighbours"].astype(np.float64)
    if present.size:
        lane_width = float(ego[Ego.LANE_WIDTH])
        lanes = lane_view(row["waypoints"], row["waypoint_mask"], lane_width)
        on_lane = present[lanes.lane_of(nb[present, NEIGHBOUR_XY], lane_width) >= 0] if lanes.paths else present[:0]
        order = on_lane[np.argsort(np.hypot(nb[on_lane, Neighbour.DX], nb[on_lane, Neighbour.DY]), kind="stable")][:5]
        for j, i in enumerate(order):
            rel_v = vel[i] - np.array([ego[Ego.SPEED], 0.0])
            out[7 * j: 7 * j + 7] = [-nb[i, Neighbour.DY], nb[i, Neighbour.DX], -rel_v[1], rel_v[0], heading[i],
                                     nb[i, Neighbour.LENGTH], nb[i, Neighbour.WIDTH]]  # fmt: skip
    pts = np.zeros((5, 3))
    k = min(5, len(target_points))
    pts[:k] = target_points[:k]
    out[35:45] = np.stack([-pts[:, 1], pts[:, 0]], axis=1).reshape(-1)
    out[45:50] = pts[:, 2]
    out[50:53] = [ego[Ego.SPEED_LIMIT], ego[Ego.LENGTH], ego[Ego.WIDTH]]
    return out


@dataclass
class _Scene:
    """What one TF step sees: ego, lanes and neighbours, the situation flags, the lane speeds
    (``v``: cur, left, right, target; lowered by leaders) and the alert box (front length, widths)."""

    ego: np.ndarray
    speed: float
    width: float
    ids: np.ndarray  # tracked neighbour ids by row
    lanes: LaneView
    cur_pts: np.ndarray
    turning: bool
    present: np.ndarray
    heading: np.ndarray
    nb_speed: np.ndarray
    nb: np.ndarray
    atten: float  # speed factor for the density around
    straight: bool
    v_lim: float
    v: dict[str, float]
    changing: bool
    w_left: float
    w_right: float
    l_front: float


class TFPlanner(StatefulPlanner):
    """TF's rules; ``stop_move`` (53 features -> True to move) adds the learned veto."""

    interface = INTERFACE

    def __init__(self, stop_move: Callable[[np.ndarray], bool] | None = None, braking_margin: bool = True):
        super().__init__()
        self.stop_move = stop_move
        self.braking_margin = braking_margin

    def new_state(self) -> TFState:
        return TFState()

    # ------------------------------------------------------------------ rule forecast
    def hits(
        self, row: dict[str, np.ndarray], rows: np.ndarray, l_front: float, w_left: float, w_right: float
    ) -> np.ndarray:
        ego = row["ego"].astype(np.float64)
        if rows.size == 0:
            return rows
        _, heading, speed, _ = neighbour_kinematics(row)
        nb = row["neighbours"].astype(np.float64)
        bearing = np.abs(np.arctan2(nb[rows, Neighbour.DY], nb[rows, Neighbour.DX]))
        rows = rows[bearing <= REAR_CONE]
        if rows.size == 0:
            return rows
        margin = ego[Ego.SPEED] ** 2 / (2 * BRAKE) if self.braking_margin else 0.0
        hit = collision_forecast(float(ego[Ego.SPEED]), float(ego[Ego.LENGTH]), float(ego[Ego.WIDTH]),
                                 nb[rows, NEIGHBOUR_XY], heading[rows], speed[rows], nb[rows, Neighbour.LENGTH],
                                 nb[rows, Neighbour.WIDTH], l_front + margin, w_left, w_right, 5)  # fmt: skip
        return rows[hit]

    def decide(self, st: TFState, row: dict[str, np.ndarray]) -> np.ndarray:
        """Situation, meta controller (learned vote, rule stop), scheduler (leader-limited lane
        speeds, lane choice, target point), then the step towards the point."""
        scene = self.scene(st, row)
        if scene is None:
            st.stopped_by = "no lane"
            return np.zeros(3)
        model_move = self.model_vote(st, row, scene)
        if self.rule_stop(st, row, scene):
            st.stopped_by = "rule"
            return np.zeros(3)
        lane_of = self.leader_speeds(st, scene)
        if not scene.changing and not model_move:
            st.stopped_by = "model"
            return np.zeros(3)
        st.stopped_by = ""
        choice = 0
        if not scene.changing:
            choice = self.lane_utility(st, row, scene.lanes, scene.v, lane_of, scene.present, scene.v_lim,
                                       scene.straight)  # fmt: skip
        aim = self.aim(st, row, scene, choice)
        if aim is None:
            st.stopped_by = "rule"
            return np.zeros(3)
        return self.step_towards(st, scene, aim, choice)

    def scene(self, st: TFState, row: dict[str, np.ndarray]) -> _Scene | None:
        """The step's situation flags, lane speeds and alert box, with the odometry counters and
        the target path updated; None off every lane."""
        ego = row["ego"].astype(np.float64)
        speed, width = float(ego[Ego.SPEED]), max(float(ego[Ego.LANE_WIDTH]), 2.0)
        ids = st.tracker.update(st.odometry.pose, speed, row["neighbours"], row["neighbour_mask"])
        moved = speed * self.dt
        st.static_cnt = st.static_cnt + 1 if moved < 0.01 else 0
        st.novice = max(st.novice - 1, 0)
        st.distance += moved
        lanes = lane_view(row["waypoints"], row["waypoint_mask"], width)
        if lanes.current < 0:
            return None
        if st.target is None or st.target not in lanes.paths:
            st.target = lanes.current
        cur_pts = lanes.paths[lanes.current]
        dh = np.abs(wrap(np.diff(cur_pts[:10, 2])))
        turning = bool((dh > np.deg2rad(5.0)).any())
        present, heading, nb_speed, _ = neighbour_kinematics(row)
        nb = row["neighbours"].astype(np.float64)
        near = int((np.hypot(nb[present, Neighbour.DX], nb[present, Neighbour.DY]) < 20.0).sum())
        straight = all((np.abs(wrap(np.diff(p[:11, 2]))) <= 1e-3).all() for p in lanes.paths.values())
        st.straight_cnt = st.straight_cnt + 1 if straight else 0
        v_lim = max(float(ego[Ego.SPEED_LIMIT]), 0.1)
        v = {"cur": v_lim, "left": v_lim if lanes.left >= 0 else 0.0, "right": v_lim if lanes.right >= 0 else 0.0}
        v["target"] = v_lim
        offset = float(ego[Ego.LANE_OFFSET])
        changing = st.target != lanes.current or abs(offset) >= width / 10
        return _Scene(
            ego=ego, speed=speed, width=width, ids=ids, lanes=lanes, cur_pts=cur_pts, turning=turning,
            present=present, heading=heading, nb_speed=nb_speed, nb=nb, atten=max(0.5, 1.0 - 0.02 * near),
            straight=straight, v_lim=v_lim, v=v, changing=changing,
            w_left=width / 2 if changing and offset < 0 and abs(offset) >= width / 10 else 1.25,
            w_right=width / 2 if changing and offset > 0 and abs(offset) >= width / 10 else 1.25,
            l_front=2.5 if changing else 7.0 if turning else 5.0,
        )  # fmt: skip

    def model_vote(self, st: TFState, row: dict[str, np.ndarray], scene: _Scene) -> bool:
        """The learned stop/move vote (move when there is no network or it is ignored), with the
        anti-deadlock window: ``DEADLOCK_STOPS`` stops while standing open ``IGNORE_STEPS`` of moving."""
        target_pts = scene.lanes.paths[st.target]
        model_move = True
        if self.stop_move is not None and not (st.model_ignore > 0 or st.novice > 0 or st.distance < 5.0
                                               or len(target_pts) < 5):  # fmt: skip
            model_move = bool(self.stop_move(stop_move_features(row, target_pts)))
        st.model_ignore = max(st.model_ignore - 1, 0)
        if not model_move:
            # counted while standing: the original's stops were instant, so its ten stops were a
            # second at rest; here a stop is a brake, and a window opened mid-brake would drive on
            st.model_stops += int(scene.speed < STANDING)
            if st.model_stops >= DEADLOCK_STOPS:
                st.model_stops, st.model_ignore = 0, IGNORE_STEPS
        else:
            st.model_stops = 0
        return model_move

    def rule_stop(self, st: TFState, row: dict[str, np.ndarray], scene: _Scene) -> bool:
        """The rule state machine: ignore for a while, hold while the blockers stay in the alert
        box (then ignore), or hold on a new forecast hit; True to stop this step."""
        box = (scene.l_front, scene.w_left, scene.w_right)
        if st.ignore > 0:
            st.ignore -= 1
        elif st.hold > 0:
            keep = [b for b in st.blockers if b in scene.ids]
            rows = np.array([int(np.flatnonzero(scene.ids == b)[0]) for b in keep], dtype=np.int64)
            still = self.hits(row, rows, *box)
            st.blockers = [int(scene.ids[r]) for r in still]
            if not st.blockers:
                st.hold = 0
            else:
                st.hold -= 1
                if st.hold == 0:
                    st.ignore = IGNORE_STEPS
                return True
        else:
            hit = self.hits(row, scene.present, *box)
            if hit.size:
                st.blockers, st.hold = [int(scene.ids[r]) for r in hit], HOLD_STEPS
                return True
        return False

    def leader_speeds(self, st: TFState, scene: _Scene) -> np.ndarray:
        """Each lane's speed limited by its leader within reach (in ``scene.v``); the lane of
        every present neighbour (-1: none)."""
        ego, nb, lanes, v = scene.ego, scene.nb, scene.lanes, scene.v
        gaps = {"left": 10.0, "right": 10.0}
        present = scene.present
        lane_of = lanes.lane_of(nb[present, NEIGHBOUR_XY], scene.width) if present.size else np.zeros(0, dtype=np.int64)
        ego_diag = float(np.hypot(ego[Ego.LENGTH], ego[Ego.WIDTH]))
        for r, lane in zip(present, lane_of):
            if lane < 0 or nb[r, Neighbour.DX] <= 0 or abs(wrap(scene.heading[r])) > np.pi / 2:
                continue
            size = float(np.hypot(nb[r, Neighbour.LENGTH], nb[r, Neighbour.WIDTH]))
            gap = max(float(np.hypot(nb[r, Neighbour.DX], nb[r, Neighbour.DY])) - ego_diag - size, 0.0)
            if lane == lanes.current and gap < 5.5:
                v["cur"] = min(v["cur"], float(scene.nb_speed[r]))
            elif scene.changing and lane == st.target and gap < 5.5:
                v["target"] = min(v["target"], float(scene.nb_speed[r]))
            elif not scene.changing:
                for side, path in (("left", lanes.left), ("right", lanes.right)):
                    if lane == path and gap < gaps[side]:
                        gaps[side] = gap
                        v[side] = min(v[side], float(scene.nb_speed[r]))
        return lane_of

    def aim(self, st: TFState, row: dict[str, np.ndarray], scene: _Scene, choice: int) -> np.ndarray | None:
        """The target point: on a lane change (``choice`` +1 left, -1 right) an early point of the
        current path, refused (None, a rule hold) when the widened alert box forecasts a hit; else
        a point of the target path, a nearer one in turns."""
        lanes = scene.lanes
        if choice:
            st.target = lanes.left if choice > 0 else lanes.right
            scene.v["target"] = scene.v[("left" if choice > 0 else "right")]
            st.final_straight_cnt = 0
            aim = scene.cur_pts[
                min(3, len(scene.cur_pts) - 1)
            ]  # the 4th point of the path before the change (as the original)
            w_left, w_right = scene.w_left, scene.w_right
            widened = (w_left + scene.width, w_right) if choice > 0 else (w_left, w_right + scene.width)
            if self.hits(row, scene.present, scene.l_front, *widened).size:
                hit = self.hits(row, scene.present, scene.l_front, *widened)
                st.blockers, st.hold = [int(scene.ids[r]) for r in hit], HOLD_STEPS
                st.target = lanes.current
                return None
        else:
            pts = lanes.paths[st.target]
            aim = pts[min(2, len(pts) - 1)]
        if scene.turning:
            pts = lanes.paths[st.target]
            aim = pts[min(1, len(pts) - 1)]
        return aim

    def step_towards(self, st: TFState, scene: _Scene, aim: np.ndarray, choice: int) -> np.ndarray:
        """The relative step towards ``aim`` at the scheduled speed, the heading change clipped."""
        # while changing lanes the target lane's leader sets the speed (the original keeps the lane
        # it left until the lane id changes; here the path is known at once)
        v_out = scene.atten * (scene.v["target"] if scene.changing or choice else scene.v["cur"])
        if scene.turning:
            v_out *= 0.5
        if st.final_straight_cnt > 0:
            v_out *= max(0.2, 0.1 * (10 - st.final_straight_cnt))
        dist = float(np.hypot(aim[0], aim[1]))
        bearing = float(np.arctan2(aim[1], aim[0])) if dist > 1e-6 else 0.0
        step = v_out * self.dt
        if dist < step:
            dx, dy = float(aim[0]), float(aim[1])
        else:
            dx, dy = step * np.cos(bearing), step * np.sin(bearing)
        turn = float(np.clip(bearing, -HEADING_CLIP, HEADING_CLIP)) if step > 1e-6 else 0.0
        return np.array([dx, dy, turn])

    def lane_utility(self, st: TFState, row: dict[str, np.ndarray], lanes: LaneView, v: dict[str, float],
                     lane_of: np.ndarray, present: np.ndarray, v_lim: float, straight: bool) -> int:  # fmt: skip
        """-1 right, 0 keep, +1 left: argmax(v_R - thr_R, v_cur, v_L - thr_L)."""
        goal = row["goal"].astype(np.float64)
        thr = {"left": 1.0, "right": 1.0}
        route = WaypointPath.ROUTE if WaypointPath.ROUTE in lanes.paths else lanes.current
        route_side = lanes.side(route)
        dist_goal = float(np.hypot(goal[Goal.DX], goal[Goal.DY])) if goal[Goal.HAS_GOAL] > 0 else np.inf
        near = 50.0 if st.straight_cnt >= 10 else 20.0
        if route_side != 0:  # off the route path: go back to it (the goal lane of the original)
            toward, away = ("left", "right") if route_side > 0 else ("right", "left")
            dec = 100.0 / max(dist_goal, 1.0) * (2.5 if straight else 1.0) if dist_goal < near else v_lim
            side_path = lanes.left if toward == "left" else lanes.right
            nb = row["neighbours"].astype(np.float64)
            occupied = any(
                lane == side_path and -6.0 <= nb[r, Neighbour.DX] <= 1.5 for r, lane in zip(present, lane_of)
            )
            if occupied and dist_goal < near and straight:
                st.final_straight_cnt += 1
                thr[toward] += 1000.0
            else:
                thr[toward] -= dec
            thr[away] += 1000.0
        elif dist_goal < near:
            thr["left"] += 1000.0
            thr["right"] += 1000.0
        hysteresis = 0.75 * v_lim if (st.novice > 0 or st.distance < 5.0) else 0.2 * v_lim
        thr["left"] += hysteresis
        thr["right"] += hysteresis
        for side, path in (("left", lanes.left), ("right", lanes.right)):
            if path < 0 or row["waypoint_mask"][path].mean() < 1.0:  # the lane must go on past the view
                thr[side] = np.inf
        utility = [v["right"] - thr["right"], v["cur"], v["left"] - thr["left"]]
        return int(np.argmax(utility)) - 1
