"""``python -m smarts.diagnostic.sensor_figure --out docs/figure1.png``: the README's sensor figure.

An agent driven by the keep-lane policy (``--policy`` picks another) approaches the signalised
two-lane intersection to turn left, among built-in traffic. The picture is its ego-centred RGB view
(road, lane centre lines, route, the ego in red, other vehicles by role, occluded ground shaded,
ground beyond the sensor range darker) with its lidar rays and hits drawn on top, and below it the
five raster layers of its observation. Everything is made by the project's own sensors from a seeded
run, so the figure regenerates identically.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from smarts.core.policies import PolicyResolver, resolve_policy

SCENARIO = "intersection_4way_signal_traffic"
SEED = 8
STEPS = 200
POLICY = "zoo:keep-lane"
VIEW_SIZE, VIEW_RESOLUTION = 512, 0.125  # 64 m across
LAYER_TILE = 96
GAP = 8
RAY_START = 2.5  # metres: rays are drawn from just outside the ego's box
LIDAR_COLOURS = {1: (255, 230, 60), 2: (255, 255, 255), 3: (255, 120, 220)}  # vehicle, pedestrian, edge


def make_figure(
    steps: int = STEPS, seed: int = SEED, policy: str = POLICY, policy_resolver: PolicyResolver | None = None
) -> np.ndarray:
    """The figure as uint8 [H, W, 3]. ``policy`` is a locator that ``policy_resolver`` (None: the
    installed default, ``smarts.core.policies``) turns into a RelativeTargetPose policy."""
    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import (
        RASTER_LAYERS,
        AgentInterface,
        LidarInterface,
        OcclusionInterface,
        RasterInterface,
    )

    interface = AgentInterface(
        occlusion=OcclusionInterface(enabled=True, mode="flag", range=28.0),
        rasters=RasterInterface(size=64, resolution=0.5, layers=RASTER_LAYERS, rgb=False),
        lidar=LidarInterface(rays=96, range=28.0),
    )
    env = DrivingParallelEnv(SCENARIO, observation=interface)
    driver = _driver(env, policy, policy_resolver, seed)
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        if not env.agents:
            break
        batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
        actions = dict(zip(env.agents, driver.act(batch)))
        obs, *_ = env.step(actions)
    if not env.agents:
        raise RuntimeError(f"{SCENARIO}: the agent left before step {steps}; pick fewer steps")
    rgb = _ego_view(env)
    mine = obs[env.agents[0]]
    env.close()
    return _with_layers(_with_lidar(rgb, mine), mine, interface.rasters.layers)


def _driver(env, policy: str, policy_resolver: PolicyResolver | None, seed: int):
    """The policy that drives, refused (closing ``env``) unless it gives direct actions in the
    scenario's action space; stepped at the scenario's step length and seeded."""
    wanted = env.scenario.agents[0].action_space
    try:
        driver = resolve_policy(policy, policy_resolver)
        acts = (getattr(driver, "action_space", None), getattr(driver, "controller", None) or "direct")
        if acts != (wanted, "direct"):
            raise ValueError(
                f"it acts in {acts[0]!r} with the {acts[1]!r} controller; the figure needs {wanted!r}, direct"
            )
    except ValueError as error:
        env.close()
        raise ValueError(f"policy {policy!r}: {error}") from error
    if hasattr(driver, "dt"):
        driver.dt = env.scenario.step_length
    if hasattr(driver, "seed"):
        driver.seed(seed)
    return driver


def _ego_view(env) -> np.ndarray:
    """The first agent's ego-centred RGB view [VIEW_SIZE, VIEW_SIZE, 3], occluded ground shaded."""
    from smarts.sensors.interface import RasterInterface
    from smarts.sensors.rasters import RasterSensor

    sim, agent = env.sim, env.sim.agent_index[env.agents[0]]
    agents = np.array([agent], dtype=np.int64)
    rows = sim.agent_row[agents]
    view = RasterSensor(RasterInterface(size=VIEW_SIZE, resolution=VIEW_RESOLUTION, layers=(), rgb=True), False)
    return view.observe(sim, agents, rows, env.builder.shadows.scan(sim, agents, rows))["rgb"][0]


def _with_lidar(rgb: np.ndarray, mine: dict):
    """Lidar rays (from just outside the ego's box) blended over the view, then the hit points."""
    from PIL import Image, ImageDraw

    centre, scale = VIEW_SIZE / 2, 1.0 / VIEW_RESOLUTION
    angles = 2 * np.pi * np.arange(len(mine["lidar"])) / len(mine["lidar"])
    ends = np.stack(
        [centre - mine["lidar"] * np.sin(angles) * scale, centre - mine["lidar"] * np.cos(angles) * scale], 1
    )
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
    return image


def _with_layers(image, mine: dict, names: tuple[str, ...]) -> np.ndarray:
    """The view above a row of the observation's raster layers, each named."""
    from PIL import Image, ImageDraw

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
    parser = argparse.ArgumentParser(
        prog="python -m smarts.diagnostic.sensor_figure", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--out", type=Path, default=Path("docs/figure1.png"), help="PNG file to write")
    parser.add_argument("--steps", type=int, default=STEPS, help=f"steps driven before the picture (default {STEPS})")
    parser.add_argument("--seed", type=int, default=SEED, help=f"episode seed (default {SEED})")
    parser.add_argument(
        "--policy", default=POLICY, help=f"locator of the RelativeTargetPose policy that drives (default {POLICY})"
    )
    args = parser.parse_args(argv)
    if args.steps < 0:
        parser.error("--steps must be >= 0")
    from PIL import Image

    try:
        figure = make_figure(args.steps, args.seed, args.policy)
    except ValueError as error:
        parser.error(f"--{error}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(figure).save(args.out, optimize=True)
    print(f"wrote {args.out} ({figure.shape[1]}x{figure.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
