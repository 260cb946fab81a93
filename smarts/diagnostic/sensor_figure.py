"""``python -m smarts.diagnostic.sensor_figure --out docs/figure1.png``: the README's sensor figure.

An agent driven by a route follower (the keep-lane rule: IDM speed along the route's waypoints,
stopping for red lights) approaches the signalised two-lane intersection to turn left, among
built-in traffic. The picture is its ego-centred RGB view (road, lane centre lines, route, the ego
in red, other vehicles by role, occluded ground shaded, ground beyond the sensor range darker) with
its lidar rays and hits drawn on top, and below it the five raster layers of its observation.
Everything is made by the project's own sensors from a seeded run, so the figure regenerates
identically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

SCENARIO = "intersection_4way_signal_traffic"
SEED = 8
STEPS = 200
VIEW_SIZE, VIEW_RESOLUTION = 512, 0.125  # 64 m across
LAYER_TILE = 96
GAP = 8
RAY_START = 2.5  # metres: rays are drawn from just outside the ego's box
LIDAR_COLOURS = {1: (255, 230, 60), 2: (255, 255, 255), 3: (255, 120, 220)}  # vehicle, pedestrian, edge


class RouteFollower:
    """The figure's driver, batched like a zoo policy: the Intelligent Driver Model's speed behind
    the nearest vehicle ahead in the lane (or a red or yellow light's stop line), moved along the
    route's waypoints in RelativeTargetPose. The same rule as ``zoo:keep-lane``, kept here so the
    docs tooling needs no agent package."""

    def __init__(self, dt: float = 0.1, accel: float = 2.0, decel: float = 3.0, time_gap: float = 1.5,
                 min_gap: float = 3.0):  # fmt: skip
        self.dt, self.accel, self.decel, self.time_gap, self.min_gap = dt, accel, decel, time_gap, min_gap

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        ego, nb, mask = obs["ego"], obs["neighbours"], obs["neighbour_mask"]
        speed = ego[:, 0].astype(np.float64)
        desired = np.maximum(ego[:, 9], 0.1)  # the lane's speed limit
        half_lane = 0.5 * np.maximum(ego[:, 8:9], 2.5)
        ahead = (mask > 0) & (nb[..., 0] > 0) & (np.abs(nb[..., 1]) < half_lane)
        gap = np.where(ahead, nb[..., 0] - 0.5 * (nb[..., 6] + ego[:, 10:11]), np.inf).min(axis=1)
        if "signal" in obs:
            sig = obs["signal"]
            stop = (sig[:, 0] + sig[:, 1] > 0) & (sig[:, 3] > 0.5 * ego[:, 10])
            gap = np.where(stop, np.minimum(gap, sig[:, 3] - 0.5 * ego[:, 10]), gap)
        closing = np.where(ahead, -nb[..., 4], 0.0)
        first = np.where(ahead, nb[..., 0], np.inf).argmin(axis=1)
        closing = closing[np.arange(len(speed)), first]
        s_star = self.min_gap + speed * self.time_gap + speed * closing / (2 * np.sqrt(self.accel * self.decel))
        free = 1.0 - (speed / desired) ** 4
        interaction = np.where(np.isfinite(gap), (np.maximum(s_star, 0.0) / np.maximum(gap, 0.1)) ** 2, 0.0)
        a = np.clip(self.accel * (free - interaction), -9.0, self.accel)
        step = np.maximum(speed + a * self.dt, 0.0) * self.dt
        wp = obs["waypoints"][:, 0, 1]  # two waypoints ahead, (x, y, heading) in the ego frame
        length = np.maximum(np.hypot(wp[:, 0], wp[:, 1]), 1e-6)
        scale = np.where(obs["waypoint_mask"][:, 0, 1] > 0, step / length, 0.0)
        action = np.stack([wp[:, 0] * scale, wp[:, 1] * scale, wp[:, 2] * scale], axis=1)
        action[scale == 0.0, 0] = step[scale == 0.0]  # no route left: straight ahead
        return action.astype(np.float32)


def make_figure(steps: int = STEPS, seed: int = SEED, policy=None) -> np.ndarray:
    """The figure as uint8 [H, W, 3]. ``policy``: a batched policy (``act({key: [n, ...]}) ->
    [n, 3]`` RelativeTargetPose actions, as the zoo's); None: ``RouteFollower``."""
    from PIL import Image, ImageDraw

    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import (
        RASTER_LAYERS,
        AgentInterface,
        LidarInterface,
        OcclusionInterface,
        RasterInterface,
    )
    from smarts.sensors.rasters import RasterSensor

    interface = AgentInterface(
        occlusion=OcclusionInterface(enabled=True, mode="flag", range=28.0),
        rasters=RasterInterface(size=64, resolution=0.5, layers=RASTER_LAYERS, rgb=False),
        lidar=LidarInterface(rays=96, range=28.0),
    )
    env = DrivingParallelEnv(SCENARIO, observation=interface)
    if policy is None:
        policy = RouteFollower(dt=env.scenario.step_length)
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        if not env.agents:
            break
        batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
        actions = dict(zip(env.agents, policy.act(batch)))
        obs, *_ = env.step(actions)
    if not env.agents:
        raise RuntimeError(f"{SCENARIO}: the agent left before step {steps}; pick fewer steps")
    sim, agent = env.sim, env.sim.agent_index[env.agents[0]]
    agents = np.array([agent], dtype=np.int64)
    rows = sim.agent_row[agents]
    view = RasterSensor(RasterInterface(size=VIEW_SIZE, resolution=VIEW_RESOLUTION, layers=(), rgb=True), False)
    rgb = view.observe(sim, agents, rows, env.builder.shadows.scan(sim, rows))["rgb"][0]
    mine = obs[env.agents[0]]
    env.close()

    # Lidar rays (from just outside the ego's box) blended over the view, then the hit points.
    centre, scale = VIEW_SIZE / 2, 1.0 / VIEW_RESOLUTION
    angles = 2 * np.pi * np.arange(len(mine["lidar"])) / len(mine["lidar"])
    ends = np.stack([centre - mine["lidar"] * np.sin(angles) * scale, centre - mine["lidar"] * np.cos(angles) * scale], 1)
    starts = np.stack([centre - RAY_START * np.sin(angles) * scale, centre - RAY_START * np.cos(angles) * scale], 1)
    base = Image.fromarray(rgb)
    rays = base.copy()
    draw = ImageDraw.Draw(rays)
    for start, end, dist in zip(starts, ends, mine["lidar"]):
        if dist > RAY_START:
            draw.line([tuple(start), tuple(end)], fill=(255, 255, 255), width=1)
    image = Image.blend(base, rays, 0.45)
    draw = ImageDraw.Draw(image)
    for (x, y), hit in zip(ends, mine["lidar_hit"]):
        if hit:
            draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=LIDAR_COLOURS[int(hit)], outline=(0, 0, 0))

    names = interface.rasters.layers
    width = max(VIEW_SIZE, len(names) * (LAYER_TILE + GAP) - GAP)
    canvas = Image.new("RGB", (width, VIEW_SIZE + GAP + LAYER_TILE + 16), (24, 24, 28))
    canvas.paste(image, ((width - VIEW_SIZE) // 2, 0))
    text = ImageDraw.Draw(canvas)
    for i, name in enumerate(names):
        layer = mine["rasters"][i].astype(np.float32)
        # Binary layers 0/1 -> black/white; occlusion 0/1/2 (range/occluded/visible) -> 3 greys.
        grey = (layer * (127 if name == "occlusion" else 255)).astype(np.uint8)
        tile = Image.fromarray(grey).resize((LAYER_TILE, LAYER_TILE), Image.NEAREST).convert("RGB")
        x = i * (LAYER_TILE + GAP) + (width - (len(names) * (LAYER_TILE + GAP) - GAP)) // 2
        canvas.paste(tile, (x, VIEW_SIZE + GAP))
        text.text((x + 2, VIEW_SIZE + GAP + LAYER_TILE + 2), name, fill=(230, 230, 230))
    return np.asarray(canvas)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m smarts.diagnostic.sensor_figure", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figure1.png"), help="PNG file to write")
    parser.add_argument("--steps", type=int, default=STEPS, help=f"steps driven before the picture (default {STEPS})")
    parser.add_argument("--seed", type=int, default=SEED, help=f"episode seed (default {SEED})")
    args = parser.parse_args(argv)
    if args.steps < 0:
        parser.error("--steps must be >= 0")
    from PIL import Image

    figure = make_figure(args.steps, args.seed)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(figure).save(args.out, optimize=True)
    print(f"wrote {args.out} ({figure.shape[1]}x{figure.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
