"""``python -m train tf-bc``: behaviour-clone TF's stop/move network from this simulator's drivers.

Demonstrations: (1) the suites' scenarios with every mission vehicle driven by keep-lane (IDM:
it stops behind leaders and at red lights), observed through TF's interface; label move (1) when
the next step's speed is at least 0.2 x the lane speed limit, else stop (0); samples near turns
(|yaw rate| >= 0.5 deg per step, +-10 steps) are kept with half as many others, TF's 2:1
turn:cruise ratio. (2) Hindsight: scripted danger situations on straight roads (a stopped car
ahead, often turned across the lane, where TF's corner-in-box forecast can miss it) driven by
TF's own rules; every step from ``--horizon`` steps before a collision is labelled stop (moving
on at the rules' speed led into it), the others with the rules' own stop/move decision (the speed
label of (1) calls a braking car "move"). The rules' keep-lane demonstrators
never showed a stop the rules do not already make; these do. Features: TF's 53
(``agents.planners.tf.stop_move_features``, the first 5 route waypoints as the "outcome" input,
as at test time). Loss: NLL + 0.5 x mean(logits^2) (d3rlpy's discrete BC), Adam lr 1e-3, batch
64. Every 5th scenario and every 5th group of 10 situations is held out; accuracy and stop
recall/precision are reported per held-out set. Writes TensorBoard logs, ``final.pt``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from train.heldout import add_run_options, apply_run_options, road_car, situation_env, split_held_out, suite_scenarios

if TYPE_CHECKING:
    import torch


def demonstrations(scenarios, seeds: int, progress: bool = True) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """scenario name -> (features [n, 53], labels [n]) with TF's turn:cruise sampling."""
    from agents.keep_lane import KeepLanePolicy
    from agents.planners.paths import valid_path
    from agents.planners.tf import INTERFACE, stop_move_features
    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import interface_from_dict
    from train.run import Bar

    interface = interface_from_dict(INTERFACE)
    driver = KeepLanePolicy()
    out = {}
    bar = Bar(total=len(scenarios) * seeds, desc="demonstrations", disable=not progress)
    rng = np.random.default_rng(0)
    for entry in scenarios:
        feats, labels, turning = [], [], []
        for seed in range(seeds):
            env = DrivingParallelEnv(entry.spec, observation=interface)
            obs, _ = env.reset(seed=seed)
            tracks: dict[str, list] = {}
            for _ in range(int(round(entry.time_limit / entry.spec.step_length))):
                if not env.agents:
                    break
                batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
                for i, a in enumerate(env.agents):
                    row = {k: v[i] for k, v in batch.items()}
                    pts = valid_path(row["waypoints"][0], row["waypoint_mask"][0])
                    tracks.setdefault(a, []).append((stop_move_features(row, pts), row["ego"][0], row["ego"][9],
                                                     abs(row["ego"][4]) * 0.1 >= np.deg2rad(0.5)))  # fmt: skip
                obs, *_ = env.step(dict(zip(env.agents, driver.act(batch))))
            env.close()
            for steps in tracks.values():
                turn = np.array([s[3] for s in steps])
                near = np.convolve(turn.astype(float), np.ones(21), mode="same") > 0
                for k in range(len(steps) - 1):
                    feats.append(steps[k][0])
                    labels.append(int(steps[k + 1][1] >= 0.2 * steps[k][2]))
                    turning.append(near[k])
            bar.update(1)
        feats_a, labels_a, turning_a = np.array(feats, dtype=np.float32), np.array(labels), np.array(turning)
        turn_idx, cruise_idx = np.flatnonzero(turning_a), np.flatnonzero(~turning_a)
        keep = max(len(turn_idx) // 2, min(len(cruise_idx), 50))
        cruise_idx = rng.choice(cruise_idx, size=min(keep, len(cruise_idx)), replace=False)
        idx = np.sort(np.concatenate([turn_idx, cruise_idx]))
        out[entry.name] = (feats_a[idx], labels_a[idx])
    bar.close()
    return out


def danger_situation(rng: np.random.Generator) -> dict:
    """A scenario dict on a straight 2- or 3-lane road: the demonstrator at 0-14 m/s, a stopped car
    3-45 m ahead in its lane (70 %) or the next one, along the lane (30 %) or across it (turned
    by 75-110 deg either way: from about 90 to 96 deg no corner of it enters TF's alert box, so
    the rules drive on), and maybe a car driving in another lane."""
    lanes = int(rng.choice([2, 3]))
    lane = int(rng.integers(lanes))
    ego_at = 40.0
    cars = [road_car(lane, ego_at, float(rng.uniform(0.0, 14.0)))]
    sides = [s for s in (lane - 1, lane + 1) if 0 <= s < lanes]
    where = lane if rng.random() < 0.7 else int(rng.choice(sides))
    turn = 0.0 if rng.random() < 0.3 else float(rng.uniform(1.3, 1.9)) * float(rng.choice([-1.0, 1.0]))
    cars.append(road_car(where, ego_at + 5.0 + float(rng.uniform(3.0, 45.0)), 0.0, "zoo:stand-still", heading=turn))
    free = [s for s in range(lanes) if s not in (lane, where)]
    if free and rng.random() < 0.5:
        cars.append(road_car(int(rng.choice(free)), ego_at + float(rng.uniform(-20.0, 20.0)), float(rng.uniform(5.0, 12.0)),
                             "zoo:keep-lane"))  # fmt: skip
    return {"map": f"builtin:straight_{lanes}lane", "agents": cars}


def hindsight(count: int, steps: int, horizon: int, progress: bool = True) -> dict[str, tuple[np.ndarray, ...]]:
    """``count`` danger situations driven by TF's own rules (``TFPlanner`` without the network),
    grouped 10 to a key ``situations_<k>``: (features, labels, hindsight flags). Labels: stop (0)
    for every step from ``horizon`` steps before a collision on (moving on at the rules' speed
    led into it; flagged), else the rules' own decision (stop when they stopped the car)."""
    from agents.planners.paths import valid_path
    from agents.planners.tf import INTERFACE, TFPlanner, stop_move_features
    from smarts.sensors.interface import interface_from_dict
    from train.run import Bar

    interface = interface_from_dict(INTERFACE)
    rng = np.random.default_rng(2)
    groups: dict[str, tuple[list, list, list]] = {}
    for k in Bar(range(count), desc="hindsight", disable=not progress):
        env, obs = situation_env(f"danger_{k}", danger_situation(rng), interface, "tf-bc situations", seed=k)
        rules = TFPlanner()
        track, crashed = [], False
        for _ in range(steps):
            if "agent_0" not in env.agents:
                break
            row = obs["agent_0"]
            target = valid_path(row["waypoints"][0], row["waypoint_mask"][0])
            batch = {key: v[None] for key, v in row.items()}
            action = rules.act(batch)[0]
            track.append((stop_move_features(row, target), rules._states[0].stopped_by != ""))
            obs, _, _, _, infos = env.step({"agent_0": action})
            if "collision" in infos.get("agent_0", {}).get("events", []):
                crashed = True
                break
        env.close()
        feats, labels, flags = groups.setdefault(f"situations_{k // 10:03d}", ([], [], []))
        n = len(track)
        for i in range(n):
            feats.append(track[i][0])
            flags.append(crashed and i >= n - horizon)
            labels.append(0 if flags[-1] or track[i][1] else 1)
    return {name: (np.array(f, dtype=np.float32), np.array(lab), np.array(fl, dtype=bool))
            for name, (f, lab, fl) in groups.items()}  # fmt: skip


def train(args: argparse.Namespace) -> dict:
    """Gather (or read) the samples, hold out whole scenarios, train the stop/move network and
    write TensorBoard logs, ``final.pt`` and ``summary.json``; the summary."""
    from torch.utils.tensorboard import SummaryWriter

    from agents.planners.nets import StopMoveNet, save_net

    apply_run_options(args)
    started = time.time()
    data, situations = samples(args, suite_scenarios(args.suite))
    split = split_samples(data, situations, args.hindsight_weight)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(out / "tensorboard")
    net = StopMoveNet(hidden=args.hidden, layers=3)
    fit(net, split, writer, args)
    metrics = {**held_metrics(net, split), "train_samples": len(split.train_y), "train_stops": int((split.train_y == 0).sum()),
               "train_hindsight_stops": split.train_hindsight, "situations": args.situations, "horizon": args.horizon,
               "hindsight_weight": args.hindsight_weight,
               "heldout_scenarios": split.held, "steps": args.steps, "batch": args.batch, "hidden": args.hidden,
               "parameters": sum(p.numel() for p in net.parameters()), "threads": args.threads,
               "minutes": round((time.time() - started) / 60, 1)}  # fmt: skip
    save_net(out / "final.pt", "tf-stop-move", net, metrics)
    (out / "summary.json").write_text(json.dumps(metrics, indent=2))
    writer.close()
    return metrics


def samples(args: argparse.Namespace, scenarios) -> tuple[dict[str, tuple], dict[str, tuple]]:
    """(suite demonstrations, hindsight situations) by scenario or group: read from ``--data``
    when the file exists, else gathered (and written to ``--data`` when given)."""
    cache = Path(args.data) if args.data else None
    if cache is not None and cache.is_file():
        with np.load(cache) as saved:
            loaded: dict[str, list] = {}
            for key in sorted(saved.files):
                name, field = key.rsplit("/", 1)
                loaded.setdefault(name, []).append(saved[key])
        data = {n: tuple(v) for n, v in loaded.items() if not n.startswith("situations_")}
        situations = {n: tuple(v) for n, v in loaded.items() if n.startswith("situations_")}
        return data, situations
    data = demonstrations(scenarios, args.seeds, not args.quiet)
    situations = (
        hindsight(args.situations, args.situation_steps, args.horizon, not args.quiet) if args.situations else {}
    )
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(cache, **{f"{n}/{i}": v for part in (data, situations) for n, d in part.items()
                                      for i, v in enumerate(d)})  # fmt: skip
    return data, situations


@dataclasses.dataclass
class Split:
    """The training samples (with how often each is drawn) and the held-out sets."""

    train_x: torch.Tensor  # [n, 53]
    train_y: torch.Tensor  # [n]: 0 stop, 1 move
    draw: torch.Tensor  # [n]: how often each sample is drawn, relatively
    held: list[str]  # the held-out scenarios and situation groups
    held_sets: dict[str, tuple[torch.Tensor, torch.Tensor]]  # "suites" / "situations" -> (features, labels)
    held_flags: torch.Tensor  # the held-out situations' hindsight flags
    train_hindsight: int


def split_samples(data: dict[str, tuple], situations: dict[str, tuple], hindsight_weight: float) -> Split:
    """Every 5th suite scenario and every 5th group of situations held out whole (``data`` takes
    the situations too)."""
    import torch

    names, held = split_held_out(list(data))
    if situations:
        sit_names, sit_held = split_held_out(list(situations)) if len(situations) >= 2 else (list(situations), [])
        data.update(situations)
        names, held = names + sit_names, held + sit_held
    train_x = torch.from_numpy(np.concatenate([data[n][0] for n in names]))
    train_y = torch.from_numpy(np.concatenate([data[n][1] for n in names]))
    # hindsight stops are about 1 % of the samples: drawn --hindsight-weight times as often
    draw = torch.from_numpy(np.concatenate([np.where(situations[n][2], hindsight_weight, 1.0) if n in situations
                                            else np.ones(len(data[n][1])) for n in names]))  # fmt: skip
    held_sets = {"suites": [n for n in held if n not in situations], "situations": [n for n in held if n in situations]}
    held_sets = {k: (torch.from_numpy(np.concatenate([data[n][0] for n in v])), torch.from_numpy(np.concatenate([data[n][1] for n in v])))
                 for k, v in held_sets.items() if v}  # fmt: skip
    held_flags = torch.from_numpy(
        np.concatenate([situations[n][2] for n in held if n in situations] or [np.zeros(0, dtype=bool)])
    )
    train_hindsight = int(sum(situations[n][2].sum() for n in names if n in situations))
    print(f"samples: {len(train_y)} train ({float((train_y == 0).float().mean()):.1%} stop), held out "
          f"{ {k: len(v[1]) for k, v in held_sets.items()} } from {held}")  # fmt: skip
    return Split(train_x, train_y, draw, held, held_sets, held_flags, train_hindsight)


def fit(net, split: Split, writer, args: argparse.Namespace) -> None:
    """``--steps`` Adam steps on weighted draws of the training samples (cross-entropy plus the
    logit penalty), the loss and the held-out metrics logged."""
    import torch

    from train.run import Bar

    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    gen = torch.Generator().manual_seed(args.seed)
    bar = Bar(range(1, args.steps + 1), desc="tf-bc", disable=args.quiet)
    for step in bar:
        idx = torch.multinomial(split.draw, args.batch, replacement=True, generator=gen)
        logits = net(split.train_x[idx])
        loss = torch.nn.functional.cross_entropy(logits, split.train_y[idx]) + args.beta * (logits**2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 20 == 0:
            writer.add_scalar("train/loss", loss.item(), step)
            bar.set_postfix(loss=f"{loss.item():.3f}")
        if step % 500 == 0 or step == args.steps:
            for k, v in held_metrics(net, split).items():
                writer.add_scalar(f"heldout/{k}", v, step)


def held_metrics(net, split: Split) -> dict[str, float]:
    """Per held-out set: accuracy, stop recall and precision against the majority class; for the
    situations also the recall of the stops only hindsight shows (the rules drove on there)."""
    import torch

    metrics = {}
    for which, (held_x, held_y) in split.held_sets.items():
        with torch.no_grad():
            pred = net(held_x).argmax(-1)
        stop_true, stop_pred = held_y == 0, pred == 0
        tp = float((stop_true & stop_pred).sum())
        metrics.update({f"{which}/accuracy": float((pred == held_y).float().mean()),
                        f"{which}/stop_recall": tp / max(float(stop_true.sum()), 1.0),
                        f"{which}/stop_precision": tp / max(float(stop_pred.sum()), 1.0),
                        f"{which}/majority_accuracy": float(max((held_y == 0).float().mean(), (held_y == 1).float().mean())),
                        f"{which}/stops": int(stop_true.sum()), f"{which}/samples": len(held_y)})  # fmt: skip
        if which == "situations":
            flag = split.held_flags
            metrics[f"{which}/hindsight_stops"] = int(flag.sum())
            metrics[f"{which}/hindsight_stop_recall"] = float(stop_pred[flag].float().mean()) if flag.any() else 0.0
    return metrics


def add_options(p: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """The options of ``python -m train tf-bc`` (its command is listed in ``train.__main__``)."""
    p.add_argument(
        "--suite", action="append", default=None, help="suites whose scenarios give demonstrations (default: both)"
    )
    p.add_argument("--seeds", type=int, default=3, help="episodes per scenario")
    p.add_argument("--out", default="runs/train/tf-bc", help="output folder (TensorBoard, final.pt)")
    p.add_argument(
        "--situations",
        type=int,
        default=1000,
        help="danger situations driven by TF's rules, labelled in hindsight (0: none)",
    )
    p.add_argument("--situation-steps", type=int, default=100, help="steps per danger situation")
    p.add_argument("--horizon", type=int, default=20, help="steps before a collision labelled stop")
    p.add_argument("--hindsight-weight", type=float, default=20.0, help="how much more often hindsight stops are drawn")
    p.add_argument("--data", default=None, help="an .npz of the samples: read when it exists, else written")
    p.add_argument("--steps", type=int, default=20000, help="gradient steps (the original's count)")
    p.add_argument("--batch", type=int, default=64, help="samples per gradient step")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    p.add_argument("--beta", type=float, default=0.5, help="weight of the logit penalty mean(logits^2)")
    p.add_argument("--hidden", type=int, default=256, help="width of the 3 hidden layers (the original: 750)")
    add_run_options(p)
    p.set_defaults(run=lambda args: (print(json.dumps(train(args), indent=2)), 0)[1])
