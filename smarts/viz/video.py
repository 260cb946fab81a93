"""Follow-camera video frames of a running simulation (``train enjoy --video``, training's
evaluation videos).

A video of the whole map makes a car a few pixels on a long road (800 x 52 pixels for a 300 m
straight road) and leaves a reader guessing which box is the agent. These frames instead follow
one agent with a fixed-scale, north-up camera (6 px/m: a car is 27 pixels long), and say what a
reader needs to follow the episode:

- a HUD band: scenario, followed agent, step and time, its speed against the lane's limit, the
  step's and the episode's task reward, and the events of the step (and the one that ended it);
- the road from the compiled map (surfaces, edges, dividers, junctions; ``smarts.replay.render``),
  the signals' stop lines in their colours, the agent's goal;
- every road user in its role's colour: the followed agent outlined, the vehicle it follows (its
  lead) in its own colour, and a legend band naming the colours; a scale bar.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from smarts.core.vehicle_table import Role
from smarts.replay.render import (
    BACKGROUND,
    FollowCanvas,
    Scene,
    draw_hud,
    draw_legend,
    draw_scale_bar,
)

ROLE_COLOURS = {
    int(Role.AGENT): (230, 60, 50),
    int(Role.SOCIAL_AGENT): (240, 160, 40),
    int(Role.TRAFFIC): (70, 130, 230),
    int(Role.REPLAY): (160, 90, 220),
    int(Role.PEDESTRIAN): (250, 250, 250),
}
"""The viewer's colours (``smarts/viz/static/viz.js``), so a video and the viewer read alike."""
LEAD_COLOUR = (29, 233, 182)
FOLLOWED_OUTLINE = (255, 235, 59)
GOAL_COLOUR = (255, 220, 0)
SIGNAL_FILL = {1: (235, 40, 40), 2: (245, 200, 30), 3: (40, 220, 80)}
LEGEND = [("agent (followed: yellow outline)", ROLE_COLOURS[int(Role.AGENT)]), ("lead", LEAD_COLOUR),
          ("social agent", ROLE_COLOURS[int(Role.SOCIAL_AGENT)]), ("traffic", ROLE_COLOURS[int(Role.TRAFFIC)]),
          ("replay", ROLE_COLOURS[int(Role.REPLAY)]), ("pedestrian", ROLE_COLOURS[int(Role.PEDESTRIAN)]),
          ("goal", GOAL_COLOUR)]  # fmt: skip


class FollowCamera:
    """Draws frames of one simulation (B = 1) following an agent; build it after ``reset`` (the
    map and signals are read once)."""

    def __init__(self, sim: Any, *, view: tuple[int, int] = (640, 400), scale: float = 6.0, scenario: str = ""):
        self.sim = sim
        self.canvas = FollowCanvas(view, scale, top=3 * 16 + 4)
        self.scene = Scene(None, sim.road_map)
        self.scenario = scenario
        self._stops = self._stop_lines(sim)
        self._centre = (0.0, 0.0)

    @staticmethod
    def _stop_lines(sim: Any) -> dict[int, np.ndarray]:
        """Incoming lane -> its end across the lane (2 x 2 points), for the lanes with a signal."""
        rm = sim.road_map
        signals = getattr(sim, "signals", None)
        if signals is None or not signals.has_signals:
            return {}
        out = {}
        for lane in np.unique(signals.from_lane).tolist():
            line = rm.lane_polyline(lane)
            d = line[-1] - line[-2] if len(line) > 1 else np.array([1.0, 0.0])
            n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9) * 0.5 * float(rm.lane_width[lane])
            out[int(lane)] = np.stack([line[-1] + n, line[-1] - n])
        return out

    def frame(self, agent: str, hud: list[str]) -> np.ndarray:
        """The picture (uint8 [H, W, 3]) of the simulation's current state, centred on ``agent``'s
        vehicle (where it was last seen once it has left); ``hud``: the text lines on top."""
        sim, canvas = self.sim, self.canvas
        t = sim.table
        a = sim.agent_index[agent]
        row = int(sim.agent_row[a]) if sim.agent_active[a] else -1
        if row >= 0:
            self._centre = (float(t.x[row]), float(t.y[row]))
        canvas.centre_on(*self._centre)
        image = Image.new("RGB", canvas.size, BACKGROUND)
        draw = ImageDraw.Draw(image)
        self.scene.draw(draw, canvas)
        self._draw_signals(draw)
        self._draw_goal(draw, a)
        rows = np.asarray(t.alive_rows, dtype=np.int64)
        x0, y0, x1, y1 = canvas.view_box()
        near = rows[(t.x[rows] > x0 - 10) & (t.x[rows] < x1 + 10) & (t.y[rows] > y0 - 10) & (t.y[rows] < y1 + 10)]
        leads = {t.row_of.get(v) for v in getattr(sim, "lead_ids", []) if v is not None} - {None}
        if near.size:
            polygons = canvas.pixels(t.corners(near))
            for r, poly in zip(near.tolist(), polygons):
                colour = LEAD_COLOUR if r in leads else ROLE_COLOURS.get(int(t.role[r]), (200, 200, 200))
                outline = FOLLOWED_OUTLINE if r == row else (0, 0, 0)
                draw.polygon([tuple(p) for p in poly], fill=colour, outline=outline, width=3 if r == row else 1)
                front, centre = poly[:2].mean(axis=0), poly.mean(axis=0)
                draw.line([tuple(centre), tuple(front)], fill=(0, 0, 0), width=2)
        bottom = canvas.size[1] - canvas.bottom
        draw_scale_bar(draw, canvas, bottom)
        draw_hud(draw, canvas.size[0], hud[:3])
        draw_legend(draw, canvas.size[0], bottom, LEGEND)
        return np.asarray(image)

    def _draw_signals(self, draw: ImageDraw.ImageDraw) -> None:
        signals = getattr(self.sim, "signals", None)
        if not self._stops or signals is None:
            return
        width = max(int(0.6 * self.canvas.scale), 2)
        for lane, ends in self._stops.items():
            colour = SIGNAL_FILL.get(int(signals.lane_colour[lane]))
            if colour is not None:
                draw.line([tuple(p) for p in self.canvas.pixels(ends)], fill=colour, width=width)

    def _draw_goal(self, draw: ImageDraw.ImageDraw, agent: int) -> None:
        from smarts.core.missions import GOAL_NONE

        ma = self.sim.mission_arrays
        if ma.goal_kind[agent] == GOAL_NONE:
            return
        gx, gy = self.canvas.pixels(np.asarray(ma.goal_xy[agent], dtype=np.float64))
        r = max(float(ma.goal_radius[agent]) * self.canvas.scale, 4.0)
        draw.ellipse([gx - r, gy - r, gx + r, gy + r], outline=GOAL_COLOUR, width=2)


def hud_lines(
    sim: Any,
    agent: str,
    *,
    scenario: str,
    step: int,
    reward: float | None,
    total: float,
    reward_name: str,
    events: list[str],
    ended: str | None = None,
) -> list[str]:
    """The HUD's three lines for ``agent`` at the simulation's current state."""
    t, rm = sim.table, sim.road_map
    a = sim.agent_index[agent]
    head = f"{scenario} · {agent} · step {step} · t = {sim.time:.1f} s"
    if sim.agent_active[a] and sim.agent_row[a] >= 0:
        r = int(sim.agent_row[a])
        lane = int(t.lane[r])
        limit = f" (limit {float(rm.lane_speed_limit[lane]):.1f})" if lane >= 0 else " (off every lane)"
        speed = f"speed {float(t.speed[r]):.1f} m/s{limit}"
    else:
        speed = "not on the road"
    step_reward = "–" if reward is None else f"{reward:+.3f}"
    second = f"{speed} · {reward_name} reward {step_reward}, {total:+.2f} so far"
    third = "events: " + (", ".join(events) if events else "none") + (f" · ended: {ended}" if ended else "")
    return [head, second, third]
