"""``python -m train vcr-classifier``: VCR's event classifier, on data its exploration policy generates.

Generator (as VCR's): every mission vehicle is driven by an exploring VCR follower: every 8
steps it picks a uniformly random observed lane path and a per-step distance from {0, 1.0, 1.2} m
(p = 0.3, 0.4, 0.3), and follows the Bezier curve over that path. It explores the suites'
scenarios and, since they hold few rear-end cases, scripted following situations on straight
roads (``following_situation``: a stopped, braking or driving lead at 4-50 m, ego speeds 0-14
m/s, cars in the neighbouring lanes). Each step stores the ego-centred rasters (drivable, route,
occupancy; 64 x 64 at 0.8 m) and ``agents.planners.vcr.classifier_numbers`` of the executed step
(the step, the next 5 path points, the ego's speed and the nearest car ahead); its label is the
first event among collision, off_road, partial_off_road (on_shoulder), wrong_way, off_route in
the next 8 steps, else safe. Safe samples are capped at 8 (suites) or 3 (situations) per
collision sample. The classifier (``agents.planners.nets.VCRClassifier``: 4 conv blocks of 32
channels, a 24 -> 64 numeric branch, a 352 -> 256 -> 64 -> 6 head) trains with cross-entropy,
Adam lr 3e-4 and weight decay 1e-3 for 15 epochs. Classes weigh 1 / sqrt(frequency) in the loss
(``--no-balance``: equal), collision ``--collision-weight`` times more. Every 5th suite scenario
and every 5th group of 10 situations is held out; accuracy and collision recall and precision
are reported per held-out set. ``--data FILE`` keeps the generated samples. Writes TensorBoard
logs and ``final.pt``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from train.heldout import add_run_options, apply_run_options, road_car, situation_env, split_held_out, suite_scenarios

CLASSES = ("collision", "off_road", "on_shoulder", "wrong_way", "off_route", "safe")
HORIZON = 8


EXPLORE_DISTANCES, EXPLORE_P = (0.0, 1.0, 1.2), (0.3, 0.4, 0.3)


def explore(env, obs: dict, steps: int, rng: np.random.Generator) -> tuple[list, list, list]:
    """One episode (from the reset observations ``obs``) with every agent of ``env`` driven by VCR's exploration policy; returns the
    per-step rasters, numbers (``agents.planners.vcr.classifier_numbers`` of the executed step)
    and labels (the first event of the next 8 steps, else safe)."""
    from agents.planners.vcr import VCRPlanner, classifier_numbers
    from smarts.core.events import Event

    order = (Event.COLLISION, Event.OFF_ROAD, Event.PARTIAL_OFF_ROAD, Event.WRONG_WAY, Event.OFF_ROUTE)
    follower = VCRPlanner()
    choice: dict[str, tuple[int, float, int]] = {}
    tracks: dict[str, list] = {}
    for _ in range(steps):
        if not env.agents:
            break
        actions = {}
        for a in env.agents:
            row = obs[a]
            path_i, dist, age = choice.get(a, (0, 1.0, HORIZON))
            if age >= HORIZON:
                valid = np.flatnonzero(row["waypoint_mask"][:, 0] > 0)
                path_i = int(rng.choice(valid)) if valid.size else 0
                dist, age = float(rng.choice(EXPLORE_DISTANCES, p=EXPLORE_P)), 0
            choice[a] = (path_i, dist, age + 1)
            mask = row["waypoint_mask"].copy()
            mask[np.arange(mask.shape[0]) != path_i] = 0.0  # only the chosen path is offered
            plan = follower.plan(follower.new_state(), {**row, "waypoint_mask": mask})
            if plan is None:
                actions[a] = np.zeros(3, dtype=np.float32)
                continue
            actions[a] = np.array([dist * plan[0, 0], dist * plan[0, 1], plan[0, 2] if dist > 0 else 0.0],
                                  dtype=np.float32)  # fmt: skip
            tracks.setdefault(a, []).append([row["rasters"], classifier_numbers(row, actions[a], plan), None])
        obs, _, _, _, infos = env.step(actions)
        for a, track in tracks.items():
            if a in actions and a in infos and track:
                happened = set(infos[a].get("events", []))
                track[-1][2] = next((i for i, e in enumerate(order) if e.name.lower() in happened), 5)
    rasters, numbers, labels = [], [], []
    for track in tracks.values():
        events = np.array([s[2] if s[2] is not None else 5 for s in track])
        for k, (raster, nums, _) in enumerate(track):
            ahead = events[k : k + HORIZON]
            bad = ahead[ahead < 5]
            rasters.append(raster)
            numbers.append(nums)
            labels.append(int(bad[0]) if bad.size else 5)
    return rasters, numbers, labels


def _cap_safe(
    rasters: list, numbers: list, labels: list, rng: np.random.Generator, ratio: int
) -> dict[str, np.ndarray]:
    """At most ``ratio`` safe samples per collision sample (at least 200)."""
    labels_a = np.array(labels, dtype=np.int64)
    safe, other = np.flatnonzero(labels_a == 5), np.flatnonzero(labels_a != 5)
    cap = max(ratio * int((labels_a == 0).sum()), 200)
    keep = np.sort(np.concatenate([other, rng.choice(safe, size=min(cap, len(safe)), replace=False)]))
    return {"rasters": np.array(rasters, dtype=np.uint8).reshape(-1, 3, 64, 64)[keep],
            "numbers": np.array(numbers, dtype=np.float32).reshape(-1, 24)[keep], "labels": labels_a[keep]}  # fmt: skip


def generate(scenarios, seeds: int, progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """scenario name -> {"rasters" uint8 [n, 3, 64, 64], "numbers" [n, 24], "labels" [n]}."""
    from agents.planners.vcr import LEARNED_INTERFACE
    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import interface_from_dict
    from train.run import Bar

    interface = interface_from_dict(LEARNED_INTERFACE)
    rng = np.random.default_rng(0)
    out = {}
    bar = Bar(total=len(scenarios) * seeds, desc="vcr data", disable=not progress)
    for entry in scenarios:
        parts = ([], [], [])
        for seed in range(seeds):
            env = DrivingParallelEnv(entry.spec, observation=interface)
            obs, _ = env.reset(seed=seed)
            for part, new in zip(parts, explore(env, obs, int(round(entry.time_limit / entry.spec.step_length)), rng)):
                part.extend(new)
            env.close()
            bar.update(1)
        out[entry.name] = _cap_safe(*parts, rng, 8)
    bar.close()
    return out


def following_situation(rng: np.random.Generator) -> dict:
    """A scenario dict on a straight 2- or 3-lane road: one explorer at 0-14 m/s behind a lead in
    its lane (stopped, braking to a stop from up to 8 m/s, or driving at the limit) 4-50 m ahead,
    and 0-2 cars in the neighbouring lanes within +-30 m (stopped or driving): rear-end
    collisions, near-misses and close-but-safe passes, which the suites rarely produce."""
    lanes = int(rng.choice([2, 3]))
    lane = int(rng.integers(lanes))
    ego_at, ego_v = 40.0, float(rng.uniform(0.0, 14.0))
    cars = [road_car(lane, ego_at, ego_v)]
    gap = float(rng.uniform(4.0, 50.0))
    kind = rng.choice(["stopped", "braking", "driving"], p=[0.5, 0.3, 0.2])
    lead_v = (
        0.0
        if kind == "stopped"
        else float(rng.uniform(2.0, 8.0))
        if kind == "braking"
        else float(rng.uniform(3.0, 12.0))
    )
    cars.append(road_car(lane, ego_at + 5.0 + gap, lead_v, "zoo:keep-lane" if kind == "driving" else "zoo:stand-still"))
    for side in [s for s in (lane - 1, lane + 1) if 0 <= s < lanes]:
        if rng.random() < 0.6:
            moving = rng.random() < 0.4
            cars.append(road_car(side, ego_at + float(rng.uniform(-30.0, 30.0)), float(rng.uniform(3.0, 12.0)) if moving else 0.0,
                             "zoo:keep-lane" if moving else "zoo:stand-still"))  # fmt: skip
    return {"map": f"builtin:straight_{lanes}lane", "agents": cars}


def generate_situations(count: int, steps: int, progress: bool = True) -> dict[str, dict[str, np.ndarray]]:
    """``count`` scripted following situations (``following_situation``), each one episode of
    ``steps`` steps, grouped 10 to a key ``situations_<k>`` (the held-out split takes whole groups)."""
    from agents.planners.vcr import LEARNED_INTERFACE
    from smarts.sensors.interface import interface_from_dict
    from train.run import Bar

    interface = interface_from_dict(LEARNED_INTERFACE)
    rng = np.random.default_rng(1)
    groups: dict[str, tuple[list, list, list]] = {}
    for k in Bar(range(count), desc="vcr situations", disable=not progress):
        env, obs = situation_env(
            f"situation_{k}", following_situation(rng), interface, "vcr-classifier situations", seed=k
        )
        parts = groups.setdefault(f"situations_{k // 10:03d}", ([], [], []))
        for part, new in zip(parts, explore(env, obs, steps, rng)):
            part.extend(new)
        env.close()
    return {name: _cap_safe(*parts, rng, 3) for name, parts in groups.items()}


def train(args: argparse.Namespace) -> dict:
    """Generate (or read) the samples, hold out whole scenarios, train the classifier and write
    TensorBoard logs, ``final.pt`` and ``summary.json``; the summary."""
    from torch.utils.tensorboard import SummaryWriter

    from agents.planners.nets import VCRClassifier, save_net

    apply_run_options(args)
    started = time.time()
    data = samples(args, suite_scenarios(args.suite))
    tr, held_sets, held, counts = split_samples(data)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(out / "tensorboard")
    weights = class_weights(counts, args.balance, args.collision_weight)
    net = VCRClassifier()
    step = fit(net, tr, weights, held_sets, writer, args)
    metrics = {**held_metrics(net, held_sets), "balanced": bool(args.balance), "collision_weight": args.collision_weight,
               "train_samples": len(tr[2]), "train_classes": dict(zip(CLASSES, counts.tolist())),
               "heldout_samples": {k: len(v[2]) for k, v in held_sets.items()},
               "heldout_classes": {k: dict(zip(CLASSES, np.bincount(v[2].numpy(), minlength=6).tolist())) for k, v in held_sets.items()},
               "heldout_scenarios": held, "epochs": args.epochs, "steps": step,
               "parameters": sum(p.numel() for p in net.parameters()), "threads": args.threads,
               "minutes": round((time.time() - started) / 60, 1)}  # fmt: skip
    save_net(out / "final.pt", "vcr-classifier", net, metrics)
    (out / "summary.json").write_text(json.dumps(metrics, indent=2))
    writer.close()
    return metrics


def samples(args: argparse.Namespace, scenarios) -> dict[str, dict[str, np.ndarray]]:
    """The samples of ``--data`` when the file exists, else generated from the suites' scenarios
    and the following situations (and written to ``--data`` when given)."""
    cache = Path(args.data) if args.data else None
    if cache is not None and cache.is_file():
        with np.load(cache) as saved:
            data = {}
            for key in saved.files:
                name, field = key.rsplit("/", 1)
                data.setdefault(name, {})[field] = saved[key]
        return data
    data = generate(scenarios, args.seeds, not args.quiet)
    data.update(generate_situations(args.situations, args.situation_steps, not args.quiet))
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(cache, **{f"{n}/{k}": v for n, d in data.items() for k, v in d.items()})
    return data


def split_samples(data: dict[str, dict[str, np.ndarray]]) -> tuple[list, dict[str, list], list[str], np.ndarray]:
    """(training tensors [rasters, numbers, labels], held-out tensors per set, the held-out
    names, training class counts): every 5th suite scenario and every 5th group of situations is
    held out whole."""
    import torch

    situations = sorted(n for n in data if n.startswith("situations_"))
    suite_names, suite_held = split_held_out([n for n in data if n not in situations])
    held_situations = split_held_out(situations)[1] if len(situations) >= 2 else []
    held = suite_held + held_situations
    names = [n for n in data if n not in held]

    def stack(which):
        return [torch.from_numpy(np.concatenate([data[n][k] for n in which])) for k in ("rasters", "numbers", "labels")]

    tr = stack(names)
    held_sets = {"suites": stack(suite_held), **({"situations": stack(held_situations)} if held_situations else {})}
    counts = np.bincount(tr[2].numpy(), minlength=6)
    print(f"samples: {len(tr[2])} train {dict(zip(CLASSES, counts.tolist()))}, held out "
          f"{ {k: len(v[2]) for k, v in held_sets.items()} } from {suite_held} and {len(held_situations)} situation groups")  # fmt: skip
    return tr, held_sets, held, counts


def class_weights(counts: np.ndarray, balance: bool, collision_weight: float):
    """The loss's class weights. Collisions are rare (a few % of the samples): classes weigh
    1 / sqrt(frequency), collision once more by ``collision_weight``, so the one class the policy
    reads is not drowned by "safe" (the original had no weights)."""
    import torch

    weights = torch.tensor(1.0 / np.sqrt(np.maximum(counts, 1) / counts.sum()), dtype=torch.float32)
    weights = weights / weights[5] if balance else torch.ones(6)
    weights[0] *= collision_weight
    return weights


def fit(net, tr: list, weights, held_sets: dict[str, list], writer, args: argparse.Namespace) -> int:
    """``--epochs`` passes of cross-entropy minibatches with Adam, the loss and the held-out
    metrics logged; the number of gradient steps."""
    import torch

    from train.run import Bar

    opt = torch.optim.Adam(net.parameters(), lr=args.lr, weight_decay=1e-3)
    gen = torch.Generator().manual_seed(args.seed)
    step = 0
    for epoch in Bar(range(1, args.epochs + 1), desc="vcr-classifier", disable=args.quiet):
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
        for k, v in held_metrics(net, held_sets).items():
            writer.add_scalar(f"heldout/{k}", v, epoch)
    return step


def held_metrics(net, held_sets: dict[str, list]) -> dict[str, float]:
    """Per held-out set: accuracy, and collision recall and precision of the argmax and of
    p(collision) >= 0.3 (where VCR's speed map halves the step)."""
    import torch

    net.eval()
    metrics = {}
    with torch.no_grad():
        for which, (rasters, numbers, labels) in held_sets.items():
            logits = torch.cat([net(rasters[i : i + 512], numbers[i : i + 512]) for i in range(0, len(labels), 512)])
            p = torch.softmax(logits, -1)[:, 0]
            pred = logits.argmax(-1)
            truth = labels == 0
            metrics[f"{which}/accuracy"] = float((pred == labels).float().mean())
            for tag, hit in (("", pred == 0), ("_p0.3", p >= 0.3)):
                tp = float((hit & truth).sum())
                metrics[f"{which}/collision_recall{tag}"] = tp / max(float(truth.sum()), 1.0)
                metrics[f"{which}/collision_precision{tag}"] = tp / max(float(hit.sum()), 1.0)
    net.train()
    return metrics


def add_options(p: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """The options of ``python -m train vcr-classifier`` (its command is listed in ``train.__main__``)."""
    p.add_argument("--suite", action="append", default=None, help="suites whose scenarios are explored (default: both)")
    p.add_argument("--seeds", type=int, default=3, help="episodes per scenario")
    p.add_argument("--out", default="runs/train/vcr-classifier", help="output folder (TensorBoard, final.pt)")
    p.add_argument("--data", default=None, help="an .npz of generated samples: read when it exists, else written")
    p.add_argument("--balance", action=argparse.BooleanOptionalAction, default=True,
                   help="weigh classes by 1 / sqrt(frequency) in the loss")  # fmt: skip
    p.add_argument("--situations", type=int, default=1500, help="scripted following situations explored (0: none)")
    p.add_argument("--situation-steps", type=int, default=80, help="steps per situation")
    p.add_argument("--collision-weight", type=float, default=2.0, help="extra loss weight of the collision class")
    p.add_argument("--epochs", type=int, default=15, help="passes over the training samples")
    p.add_argument("--batch", type=int, default=100, help="samples per gradient step")
    p.add_argument("--lr", type=float, default=3e-4, help="Adam learning rate")
    add_run_options(p)
    p.set_defaults(run=lambda args: (print(json.dumps(train(args), indent=2)), 0)[1])
