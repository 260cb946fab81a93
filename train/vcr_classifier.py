"""``python -m train vcr-classifier``: VCR's event classifier, on data its exploration policy generates.

Generator (as VCR's): the suites' scenarios with every mission vehicle driven by an exploring
VCR follower: every 8 steps it picks a uniformly random observed lane path and a per-step
distance from {0, 1.0, 1.2} m (p = 0.3, 0.4, 0.3), and follows the Bezier curve over that path.
Each step stores the ego-centred rasters (drivable, route, occupancy; 64 x 64 at 0.8 m) and the
executed step (ego frame) with the next 5 path points; its label is the
first event among collision, off_road, partial_off_road (on_shoulder), wrong_way, off_route in
the next 8 steps, else safe. Safe samples are capped at 8 per collision sample per scenario
(at least 200). The classifier (``agents.planners.nets.VCRClassifier``: 4 conv blocks of 32
channels, a 18 -> 64 numeric branch, a 352 -> 256 -> 64 -> 6 head) trains with cross-entropy,
Adam lr 3e-4 and weight decay 1e-3 for 15 epochs; scenarios are split by name and the held-out
collision precision and recall are reported. Classes weigh 1 / sqrt(frequency) in the loss
(``--no-balance``: equal). ``--data FILE`` keeps the generated samples. Writes TensorBoard logs
and ``final.pt``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch

from train.heldout import add_run_options, apply_run_options, split_held_out, suite_scenarios

CLASSES = ("collision", "off_road", "on_shoulder", "wrong_way", "off_route", "safe")
HORIZON = 8


def _numbers(action: np.ndarray, path: np.ndarray) -> np.ndarray:
    """The executed step (x, y, heading) and the next 5 path points, ego frame: 18 numbers."""
    pts = np.zeros((6, 3), dtype=np.float32)
    pts[0] = action
    k = min(5, len(path) - 1)
    pts[1 : 1 + k] = path[1 : 1 + k]
    return pts.reshape(-1)


def generate(scenarios, seeds: int, progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """scenario name -> {"rasters" uint8 [n, 3, 64, 64], "numbers" [n, 18], "labels" [n]}."""
    from tqdm import tqdm

    from agents.planners.vcr import LEARNED_INTERFACE, VCRPlanner
    from smarts.core.events import Event
    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import interface_from_dict

    interface = interface_from_dict(LEARNED_INTERFACE)
    order = (Event.COLLISION, Event.OFF_ROAD, Event.PARTIAL_OFF_ROAD, Event.WRONG_WAY, Event.OFF_ROUTE)
    rng = np.random.default_rng(0)
    out = {}
    bar = tqdm(total=len(scenarios) * seeds, desc="vcr data", disable=not progress)
    for entry in scenarios:
        rasters, numbers, labels = [], [], []
        for seed in range(seeds):
            env = DrivingParallelEnv(dataclasses.replace(entry.spec), observation=interface)
            obs, _ = env.reset(seed=seed)
            follower = VCRPlanner()
            choice: dict[str, tuple[int, float, int]] = {}
            tracks: dict[str, list] = {}
            for _ in range(int(round(entry.time_limit / entry.spec.step_length))):
                if not env.agents:
                    break
                actions = {}
                for a in env.agents:
                    row = obs[a]
                    path_i, dist, age = choice.get(a, (0, 1.0, HORIZON))
                    if age >= HORIZON:
                        valid = np.flatnonzero(row["waypoint_mask"][:, 0] > 0)
                        path_i = int(rng.choice(valid)) if valid.size else 0
                        dist, age = float(rng.choice([0.0, 1.0, 1.2], p=[0.3, 0.4, 0.3])), 0
                    choice[a] = (path_i, dist, age + 1)
                    state = follower.new_state()
                    mask = row["waypoint_mask"].copy()
                    mask[np.arange(3) != path_i] = 0.0  # only the chosen path is offered
                    plan = follower.plan(state, {**row, "waypoint_mask": mask})
                    if plan is None:
                        actions[a] = np.zeros(3, dtype=np.float32)
                        continue
                    actions[a] = np.array([dist * plan[0, 0], dist * plan[0, 1], plan[0, 2] if dist > 0 else 0.0],
                                          dtype=np.float32)  # fmt: skip
                    tracks.setdefault(a, []).append([row["rasters"], _numbers(actions[a], plan), None])
                obs, _, _, _, infos = env.step(actions)
                for a, steps in tracks.items():
                    if a in actions and a in infos and steps:
                        happened = set(infos[a].get("events", []))
                        steps[-1][2] = next((i for i, e in enumerate(order) if e.name.lower() in happened), 5)
            env.close()
            for steps in tracks.values():
                events = np.array([s[2] if s[2] is not None else 5 for s in steps])
                for k, (raster, nums, _) in enumerate(steps):
                    ahead = events[k : k + HORIZON]
                    bad = ahead[ahead < 5]
                    rasters.append(raster)
                    numbers.append(nums)
                    labels.append(int(bad[0]) if bad.size else 5)
            bar.update(1)
        labels_a = np.array(labels)
        safe, other = np.flatnonzero(labels_a == 5), np.flatnonzero(labels_a != 5)
        cap = max(8 * int((labels_a == 0).sum()), 200)
        keep = np.sort(np.concatenate([other, rng.choice(safe, size=min(cap, len(safe)), replace=False)]))
        out[entry.name] = {"rasters": np.array(rasters, dtype=np.uint8)[keep],
                           "numbers": np.array(numbers, dtype=np.float32)[keep], "labels": labels_a[keep]}  # fmt: skip
    bar.close()
    return out


def train(args: argparse.Namespace) -> dict:
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    from agents.planners.nets import VCRClassifier, save_net

    apply_run_options(args)
    started = time.time()
    scenarios = suite_scenarios(args.suite)
    cache = Path(args.data) if args.data else None
    if cache is not None and cache.is_file():
        with np.load(cache) as saved:
            data = {}
            for key in saved.files:
                name, field = key.rsplit("/", 1)
                data.setdefault(name, {})[field] = saved[key]
    else:
        data = generate(scenarios, args.seeds, not args.quiet)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(cache, **{f"{n}/{k}": v for n, d in data.items() for k, v in d.items()})
    names, held = split_held_out(list(data))

    def stack(which):
        return [torch.from_numpy(np.concatenate([data[n][k] for n in which])) for k in ("rasters", "numbers", "labels")]

    tr, ho = stack(names), stack(held)
    counts = np.bincount(tr[2].numpy(), minlength=6)
    print(f"samples: {len(tr[2])} train {dict(zip(CLASSES, counts.tolist()))}, {len(ho[2])} held out from {held}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(out / "tensorboard")
    # Collisions are rare (a few % of the samples): classes weigh 1 / sqrt(frequency), so the
    # one class the policy reads is not drowned by "safe" (the original had no weights).
    weights = torch.tensor(1.0 / np.sqrt(np.maximum(counts, 1) / counts.sum()), dtype=torch.float32)
    weights = weights / weights[5] if args.balance else torch.ones(6)
    net = VCRClassifier()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr, weight_decay=1e-3)
    gen = torch.Generator().manual_seed(args.seed)

    def held_metrics() -> dict[str, float]:
        net.eval()
        with torch.no_grad():
            pred = torch.cat([net(ho[0][i : i + 512], ho[1][i : i + 512]).argmax(-1) for i in range(0, len(ho[2]), 512)])
        net.train()
        tp = float(((pred == 0) & (ho[2] == 0)).sum())
        return {"accuracy": float((pred == ho[2]).float().mean()),
                "collision_recall": tp / max(float((ho[2] == 0).sum()), 1.0),
                "collision_precision": tp / max(float((pred == 0).sum()), 1.0)}  # fmt: skip

    step = 0
    for epoch in tqdm(range(1, args.epochs + 1), desc="vcr-classifier", disable=args.quiet):
        perm = torch.randperm(len(tr[2]), generator=gen)
        for i in range(0, len(perm), args.batch):
            idx = perm[i : i + args.batch]
            loss = torch.nn.functional.cross_entropy(net(tr[0][idx], tr[1][idx]), tr[2][idx], weight=weights)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            if step % 20 == 0:
                writer.add_scalar("train/loss", loss.item(), step)
        for k, v in held_metrics().items():
            writer.add_scalar(f"heldout/{k}", v, epoch)
    metrics = {**held_metrics(), "balanced": bool(args.balance), "train_samples": len(tr[2]), "train_classes": dict(zip(CLASSES, counts.tolist())),
               "heldout_samples": len(ho[2]), "heldout_collisions": int((ho[2] == 0).sum()),
               "heldout_scenarios": held, "epochs": args.epochs, "steps": step,
               "parameters": sum(p.numel() for p in net.parameters()), "threads": args.threads,
               "minutes": round((time.time() - started) / 60, 1)}  # fmt: skip
    save_net(out / "final.pt", "vcr-classifier", net, metrics)
    (out / "summary.json").write_text(json.dumps(metrics, indent=2))
    writer.close()
    return metrics


def add_parser(sub) -> None:
    p = sub.add_parser("vcr-classifier", help="generate VCR's exploration data and train its event classifier",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    p.add_argument("--suite", action="append", default=None, help="suites whose scenarios are explored (default: both)")
    p.add_argument("--seeds", type=int, default=3, help="episodes per scenario")
    p.add_argument("--out", default="runs/train/vcr-classifier", help="output folder (TensorBoard, final.pt)")
    p.add_argument("--data", default=None, help="an .npz of generated samples: read when it exists, else written")
    p.add_argument("--balance", action=argparse.BooleanOptionalAction, default=True,
                   help="weigh classes by 1 / sqrt(frequency) in the loss")  # fmt: skip
    p.add_argument("--epochs", type=int, default=15, help="passes over the training samples")
    p.add_argument("--batch", type=int, default=100, help="samples per gradient step")
    p.add_argument("--lr", type=float, default=3e-4, help="Adam learning rate")
    add_run_options(p)
    p.set_defaults(run=lambda args: (print(json.dumps(train(args), indent=2)), 0)[1])
