"""``python -m train tf-bc``: behaviour-clone TF's stop/move network from this simulator's drivers.

Demonstrations: the suites' scenarios with every mission vehicle driven by keep-lane (IDM: it
stops behind leaders and at red lights), observed through TF's interface. Each agent step gives
TF's 53 features (``agents.planners.tf.stop_move_features``, the first 5 route waypoints as the
"outcome" input, as at test time) and the label move (1) when the next step's speed is at least
0.2 x the lane speed limit, else stop (0). Samples near turns (|yaw rate| >= 0.5 deg per step,
+-10 steps) are kept with half as many others, TF's 2:1 turn:cruise ratio. Loss: NLL + 0.5 x
mean(logits^2) (d3rlpy's discrete BC), Adam lr 1e-3, batch 64. Scenarios are split by name;
held-out accuracy and stop recall/precision are reported. Writes TensorBoard logs, ``final.pt``.
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


def demonstrations(scenarios, seeds: int, progress: bool = True) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """scenario name -> (features [n, 53], labels [n]) with TF's turn:cruise sampling."""
    from tqdm import tqdm

    from agents.keep_lane import KeepLanePolicy
    from agents.planners.paths import valid_path
    from agents.planners.tf import INTERFACE, stop_move_features
    from smarts.env import DrivingParallelEnv
    from smarts.sensors.interface import interface_from_dict

    interface = interface_from_dict(INTERFACE)
    driver = KeepLanePolicy()
    out = {}
    bar = tqdm(total=len(scenarios) * seeds, desc="demonstrations", disable=not progress)
    rng = np.random.default_rng(0)
    for entry in scenarios:
        feats, labels, turning = [], [], []
        for seed in range(seeds):
            env = DrivingParallelEnv(dataclasses.replace(entry.spec), observation=interface)
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


def train(args: argparse.Namespace) -> dict:
    from torch.utils.tensorboard import SummaryWriter
    from tqdm import tqdm

    from agents.planners.nets import StopMoveNet, save_net

    apply_run_options(args)
    started = time.time()
    scenarios = suite_scenarios(args.suite)
    data = demonstrations(scenarios, args.seeds, not args.quiet)
    names, held = split_held_out(list(data))
    train_x = torch.from_numpy(np.concatenate([data[n][0] for n in names]))
    train_y = torch.from_numpy(np.concatenate([data[n][1] for n in names]))
    held_x = torch.from_numpy(np.concatenate([data[n][0] for n in held]))
    held_y = torch.from_numpy(np.concatenate([data[n][1] for n in held]))
    print(f"samples: {len(train_y)} train ({float((train_y == 0).float().mean()):.1%} stop), {len(held_y)} held out "
          f"from {held}")  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(out / "tensorboard")
    net = StopMoveNet(hidden=args.hidden, layers=3)
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    gen = torch.Generator().manual_seed(args.seed)

    def held_metrics() -> dict[str, float]:
        with torch.no_grad():
            pred = net(held_x).argmax(-1)
        stop_true, stop_pred = held_y == 0, pred == 0
        tp = float((stop_true & stop_pred).sum())
        return {"accuracy": float((pred == held_y).float().mean()),
                "stop_recall": tp / max(float(stop_true.sum()), 1.0),
                "stop_precision": tp / max(float(stop_pred.sum()), 1.0),
                "majority_accuracy": float(max((held_y == 0).float().mean(), (held_y == 1).float().mean()))}  # fmt: skip

    bar = tqdm(range(1, args.steps + 1), desc="tf-bc", disable=args.quiet)
    for step in bar:
        idx = torch.randint(0, len(train_y), (args.batch,), generator=gen)
        logits = net(train_x[idx])
        loss = torch.nn.functional.cross_entropy(logits, train_y[idx]) + args.beta * (logits**2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step % 20 == 0:
            writer.add_scalar("train/loss", loss.item(), step)
            bar.set_postfix(loss=f"{loss.item():.3f}")
        if step % 500 == 0 or step == args.steps:
            for k, v in held_metrics().items():
                writer.add_scalar(f"heldout/{k}", v, step)
    metrics = {**held_metrics(), "train_samples": len(train_y), "heldout_samples": len(held_y),
               "heldout_scenarios": held, "steps": args.steps, "batch": args.batch, "hidden": args.hidden,
               "parameters": sum(p.numel() for p in net.parameters()), "threads": args.threads,
               "minutes": round((time.time() - started) / 60, 1)}  # fmt: skip
    save_net(out / "final.pt", "tf-stop-move", net, metrics)
    (out / "summary.json").write_text(json.dumps(metrics, indent=2))
    writer.close()
    return metrics


def add_parser(sub) -> None:
    p = sub.add_parser("tf-bc", help="behaviour-clone TF's stop/move network from keep-lane demonstrations",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    p.add_argument("--suite", action="append", default=None, help="suites whose scenarios give demonstrations (default: both)")
    p.add_argument("--seeds", type=int, default=3, help="episodes per scenario")
    p.add_argument("--out", default="runs/train/tf-bc", help="output folder (TensorBoard, final.pt)")
    p.add_argument("--steps", type=int, default=3000, help="gradient steps")
    p.add_argument("--batch", type=int, default=64, help="samples per gradient step")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    p.add_argument("--beta", type=float, default=0.5, help="weight of the logit penalty mean(logits^2)")
    p.add_argument("--hidden", type=int, default=256, help="width of the 3 hidden layers (the original: 750)")
    add_run_options(p)
    p.set_defaults(run=lambda args: (print(json.dumps(train(args), indent=2)), 0)[1])
