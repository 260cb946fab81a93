"""``python -m train aid-predictor``: train AID's motion predictor on logged trajectories.

Samples are built as the original did: a random time step, a random vehicle as the "ego", its 5
nearest others, 11 history and 30 future states, all in that vehicle's frame at the time step
(x, y, relative heading, vx, vy; zero where a vehicle was not seen, stopping at the first gap
going back). Loss: the best of 3 modes by mean L2 at every 5th future step, smooth-L1 on it plus
0.5 cross-entropy of the mode scores. Scenarios are split by name: the held-out ones report the
3 s final displacement error (FDE) of the highest-scored mode beside constant velocity's; the
model is accepted (``accepted`` in the checkpoint's metrics) when it beats constant velocity there.
Writes TensorBoard logs, ``best.pt`` and ``final.pt`` (weights only) under ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

from train.heldout import add_run_options, apply_run_options, split_held_out

HIST, FUT, NB = 11, 30, 5


def _frame(states: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World states [..., >=4] (x, y, heading, speed) -> (x, y, rel heading, vx, vy) in ``pose``'s frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = states[..., 0] - pose[0], states[..., 1] - pose[1]
    rel = (states[..., 2] - pose[2] + np.pi) % (2 * np.pi) - np.pi
    v = states[..., 3]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, rel, v * np.cos(rel), v * np.sin(rel)], axis=-1)


def history(ep: np.ndarray, vehicle: int, t: int, pose: np.ndarray) -> np.ndarray:
    """[11, 5] features of frames t-10..t, zero before the most recent gap."""
    out = np.zeros((HIST, 5), dtype=np.float32)
    for k in range(HIST):
        f = t - k
        if f < 0 or ep[f, vehicle, 6] == 0:
            break
        out[HIST - 1 - k] = _frame(ep[f, vehicle], pose)
    return out


def samples_from_episode(ep: np.ndarray, count: int, rng: np.random.Generator) -> list[tuple[np.ndarray, ...]]:
    """``count`` (ego [11, 5], neighbours [5, 11, 5], future [5, 30, 3], future mask [5, 30])."""
    T = ep.shape[0]
    out = []
    if T < HIST + 15:
        return out
    for _ in range(count * 4):
        if len(out) >= count:
            break
        t = int(rng.integers(HIST - 1, T - 15))
        present = np.flatnonzero(ep[t, :, 6] > 0)
        if present.size < 2:
            continue
        ego = int(rng.choice(present))
        pose = ep[t, ego, :3].astype(np.float64)
        others = present[present != ego]
        dist = np.hypot(ep[t, others, 0] - pose[0], ep[t, others, 1] - pose[1])
        others = others[np.argsort(dist, kind="stable")[:NB]]
        nb = np.zeros((NB, HIST, 5), dtype=np.float32)
        fut = np.zeros((NB, FUT, 3), dtype=np.float32)
        mask = np.zeros((NB, FUT), dtype=np.float32)
        for j, v in enumerate(others):
            nb[j] = history(ep, int(v), t, pose)
            frames = np.arange(t + 1, min(t + 1 + FUT, T))
            seen = ep[frames, v, 6] > 0
            fut[j, : len(frames)] = _frame(ep[frames, v], pose)[:, :3] * seen[:, None]
            mask[j, : len(frames)] = seen
        out.append((history(ep, ego, t, pose), nb, fut, mask))
    return out


def build_set(files: list[Path], per_episode: int, seed: int) -> dict[str, torch.Tensor]:
    import torch

    rng = np.random.default_rng(seed)
    rows: list[tuple[np.ndarray, ...]] = []
    for path in files:
        with np.load(path) as data:
            for key in sorted(data.files):
                rows += samples_from_episode(data[key], per_episode, rng)
    if not rows:
        raise ValueError(f"no samples in {[f.name for f in files]}: episodes need 26+ steps and 2+ vehicles")
    names = ("ego", "neighbours", "future", "mask")
    return {n: torch.from_numpy(np.stack([r[i] for r in rows])) for i, n in enumerate(names)}


def loss_fn(trajs: torch.Tensor, scores: torch.Tensor, future: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    import torch

    valid = mask.sum(-1) > 0  # [B, N]
    idx = torch.arange(4, FUT, 5)
    err = torch.linalg.norm(trajs[..., idx, :2] - future[:, :, None, idx, :2], dim=-1)  # [B, N, M, 6]
    m = mask[:, :, None, idx]
    mean_err = (err * m).sum(-1) / m.sum(-1).clamp(min=1)
    best = mean_err.argmin(-1)  # [B, N]
    pick = torch.gather(trajs, 2, best[:, :, None, None, None].expand(-1, -1, 1, FUT, 3))[:, :, 0]
    reg = torch.nn.functional.smooth_l1_loss(pick * mask[..., None], future * mask[..., None], reduction="none")
    reg = reg.sum((-1, -2))[valid].sum() / mask[valid].sum().clamp(min=1)
    ce = torch.nn.functional.cross_entropy(scores[valid], best[valid]) if valid.any() else scores.sum() * 0
    return reg + 0.5 * ce


def evaluate(net, data: dict[str, torch.Tensor], batch: int = 256) -> dict[str, float]:
    """FDE and ADE (m) of the highest-scored mode and of constant velocity, over neighbours seen 3 s later."""
    import torch

    with torch.no_grad():
        net.eval()
        sums = {"fde": 0.0, "ade": 0.0, "cv_fde": 0.0, "cv_ade": 0.0, "min_fde": 0.0}
        count, points = 0, 0
        t = torch.arange(1, FUT + 1, dtype=torch.float32) * 0.1
        for i in range(0, len(data["ego"]), batch):
            ego, nb, fut, mask = (data[k][i : i + batch] for k in ("ego", "neighbours", "future", "mask"))
            trajs, scores = net(ego, nb)
            top = torch.gather(trajs, 2, scores.argmax(-1)[:, :, None, None, None].expand(-1, -1, 1, FUT, 3))[
                :, :, 0, :, :2
            ]
            cur = nb[:, :, -1]
            cv = cur[:, :, None, :2] + cur[:, :, None, 3:5] * t[None, None, :, None]
            end = mask[:, :, -1] > 0
            end &= nb[:, :, -1].abs().sum(-1) > 0
            err = torch.linalg.norm(top - fut[..., :2], dim=-1)
            cv_err = torch.linalg.norm(cv - fut[..., :2], dim=-1)
            all_err = torch.linalg.norm(trajs[..., -1, :2] - fut[:, :, None, -1, :2], dim=-1).min(-1).values
            m = mask * end[..., None]
            sums["fde"] += float(err[..., -1][end].sum())
            sums["cv_fde"] += float(cv_err[..., -1][end].sum())
            sums["min_fde"] += float(all_err[end].sum())
            sums["ade"] += float((err * m).sum())
            sums["cv_ade"] += float((cv_err * m).sum())
            count += int(end.sum())
            points += int(m.sum())
        net.train()
        out = {k: v / max(count, 1) for k, v in sums.items() if "fde" in k}
        out.update({k: v / max(points, 1) for k, v in sums.items() if "ade" in k})
        out["neighbours"] = count
        return out


def train(args: argparse.Namespace) -> dict:
    import torch
    from torch.utils.tensorboard import SummaryWriter

    from agents.planners.nets import AIDPredictor, save_net
    from train.run import Bar

    apply_run_options(args)
    files = sorted(Path(args.data).glob("*.npz"))
    if not files:
        raise ValueError(f"{args.data}: no trajectory files (*.npz); log some with `python -m train trajectories`")
    train_files, held_files = split_held_out(files)
    started = time.time()
    train_set = build_set(train_files, args.per_episode, args.seed)
    held_set = build_set(held_files, max(args.per_episode // 4, 1), args.seed + 1)
    print(f"samples: {len(train_set['ego'])} train from {len(train_files)} scenarios, "
          f"{len(held_set['ego'])} held out from {[f.stem for f in held_files]}")  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    writer = SummaryWriter(out / "tensorboard")
    net = AIDPredictor(d=args.d, heads=args.heads, ffn=args.ffn, rounds=args.rounds)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=max(args.steps // 10, 1), gamma=0.9)
    gen = torch.Generator().manual_seed(args.seed)
    n = len(train_set["ego"])
    best, best_metrics = np.inf, {}
    bar = Bar(range(1, args.steps + 1), desc="aid-predictor", disable=args.quiet)
    for step in bar:
        idx = torch.randint(0, n, (args.batch,), generator=gen)
        trajs, scores = net(train_set["ego"][idx], train_set["neighbours"][idx])
        loss = loss_fn(trajs, scores, train_set["future"][idx], train_set["mask"][idx])
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
        opt.step()
        sched.step()
        if step % 20 == 0:
            writer.add_scalar("train/loss", loss.item(), step)
            bar.set_postfix(loss=f"{loss.item():.3f}")
        if step % args.eval_every == 0 or step == args.steps:
            metrics = evaluate(net, held_set)
            for k, v in metrics.items():
                writer.add_scalar(f"heldout/{k}", v, step)
            if metrics["fde"] < best:
                best, best_metrics = metrics["fde"], {**metrics, "step": step}
                save_net(out / "best.pt", "aid-predictor", net, best_metrics)
            Bar.write(f"step {step}: held-out FDE {metrics['fde']:.2f} m (CV {metrics['cv_fde']:.2f} m, "
                       f"min over modes {metrics['min_fde']:.2f} m)")  # fmt: skip
    minutes = (time.time() - started) / 60
    summary = {**best_metrics, "accepted": bool(best_metrics.get("fde", np.inf) < best_metrics.get("cv_fde", 0.0)),
               "train_samples": n, "heldout_samples": len(held_set["ego"]),
               "heldout_scenarios": [f.stem for f in held_files], "minutes": round(minutes, 1),
               "parameters": sum(p.numel() for p in net.parameters()), "threads": args.threads,
               "config": net.config, "steps": args.steps, "batch": args.batch, "lr": args.lr}  # fmt: skip
    save_net(out / "final.pt", "aid-predictor", net, summary)
    from agents.planners.nets import load_net

    best_net, _ = load_net(out / "best.pt", "aid-predictor")
    save_net(out / "best.pt", "aid-predictor", best_net, summary)
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    writer.close()
    return summary


def add_options(p: argparse.ArgumentParser, argv: list[str] | None = None) -> None:
    """The options of ``python -m train aid-predictor`` (its command is listed in ``train.__main__``)."""
    p.add_argument("--data", default="runs/data/trajectories", help="folder of `train trajectories` files")
    p.add_argument("--out", default="runs/train/aid-predictor", help="output folder (TensorBoard, best.pt, final.pt)")
    p.add_argument("--steps", type=int, default=2500, help="gradient steps")
    p.add_argument("--batch", type=int, default=64, help="samples per gradient step")
    p.add_argument("--lr", type=float, default=5e-4, help="AdamW learning rate (StepLR x0.9 every steps/10)")
    p.add_argument("--d", type=int, default=64, help="model width")
    p.add_argument("--heads", type=int, default=4, help="attention heads")
    p.add_argument("--ffn", type=int, default=128, help="feed-forward width")
    p.add_argument("--rounds", type=int, default=2, help="(temporal, social) attention rounds")
    p.add_argument("--per-episode", type=int, default=200, help="samples drawn per logged episode")
    p.add_argument("--eval-every", type=int, default=500, help="steps between held-out evaluations")
    add_run_options(p)
    p.set_defaults(run=lambda args: (print(json.dumps(train(args), indent=2)), 0)[1])
