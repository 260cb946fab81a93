"""The benchmark report: results JSON/CSV, a Markdown table, plots and TensorBoard scalars.

Everything is computed from the episode logs on disk through ``smarts.benchmark.metrics``, so a
report can be rebuilt from a run folder alone.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from smarts.benchmark.metrics import load_params, read_episode, score_suite
from smarts.benchmark.metrics.scores import metric_names
from smarts.benchmark.suites import Suite


def write_report(out: Path, suite: Suite, agents: list[str], results: list[dict]) -> Path:
    """Score each agent's logs and write ``results.json``, ``results.csv``, ``report.md``,
    ``plots/`` and TensorBoard events under ``out``; returns the report path."""
    from smarts.benchmark.runner import agent_label

    out = Path(out)
    params = load_params()
    names = metric_names(suite.task)
    scores = {}
    crashed = {}
    for agent in agents:
        mine = [r for r in results if r["agent"] == agent]
        logs = [read_episode(r["log"]) for r in mine if r.get("log")]
        crashed[agent] = [r for r in mine if not r.get("log")]
        scores[agent] = score_suite(logs, params) if logs else None

    doc = {
        "suite": suite.name,
        "task": suite.task,
        "scenarios": [{"name": s.name, "difficulty": s.difficulty, "time_limit": s.time_limit} for s in suite.scenarios],
        "agents": {
            agent: {
                "scores": s.to_dict() if s is not None else None,
                "crashed_episodes": crashed[agent],
            }
            for agent, s in scores.items()
        },
    }
    (out / "results.json").write_text(json.dumps(doc, indent=2, default=float))
    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["agent", "scenario", "difficulty", "episodes", *names])
        difficulty = {s.name: s.difficulty for s in suite.scenarios}
        for agent, s in scores.items():
            if s is None:
                continue
            for scenario, row in s.scenarios.items():
                writer.writerow([agent, scenario, difficulty.get(scenario, ""), s.episodes[scenario], *(f"{row[n]:.4f}" for n in names)])
            writer.writerow([agent, "overall", "", sum(s.episodes.values()), *(f"{s.overall[n]:.4f}" for n in names)])

    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    _metric_plots(plots, suite, scores, names)
    _trajectory_plots(plots, suite, agents, results)
    _tensorboard(out / "tensorboard", suite, scores, names, agent_label)

    lines = [f"# Benchmark: {suite.name} ({suite.task})", ""]
    lines += [f"{len(suite.scenarios)} scenarios; episodes per scenario as listed below.", ""]
    lines += ["| method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for agent, s in scores.items():
        if s is None:
            lines.append(f"| {agent} | " + " | ".join("n/a" for _ in names) + " |")
        else:
            lines.append(f"| {agent} | " + " | ".join(f"{s.overall[n]:.3f}" for n in names) + " |")
    lines += ["", "## Per scenario (S_bench)", "", "| scenario | difficulty | " + " | ".join(agents) + " |",
              "|---|---|" + "---:|" * len(agents)]  # fmt: skip
    for entry in suite.scenarios:
        cells = []
        for agent in agents:
            s = scores[agent]
            row = s.scenarios.get(entry.name) if s is not None else None
            cells.append(f"{row['S_bench']:.3f}" if row else "n/a")
        lines.append(f"| {entry.name} | {entry.difficulty} | " + " | ".join(cells) + " |")
    failures = [(a, f) for a, s in scores.items() if s is not None for f in s.failed]
    failures += [(a, c) for a, cs in crashed.items() for c in cs]
    if failures:
        lines += ["", "## Failed episodes", ""]
        lines += [f"- {a}: {f.get('scenario', '?')} #{f.get('episode')}: {f.get('failure')}" for a, f in failures]
    lines += ["", "Plots: `plots/`; TensorBoard: `tensorboard --logdir " + str(out / "tensorboard") + "`."]
    report = out / "report.md"
    report.write_text("\n".join(lines) + "\n")
    return report


def _metric_plots(plots: Path, suite: Suite, scores: dict, names: tuple[str, ...]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenario_names = [s.name for s in suite.scenarios]
    agents = [a for a, s in scores.items() if s is not None]
    for name in names:
        fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(scenario_names) + 2), 3.5))
        width = 0.8 / max(len(agents), 1)
        x = np.arange(len(scenario_names))
        for k, agent in enumerate(agents):
            values = [scores[agent].scenarios.get(s, {}).get(name, np.nan) for s in scenario_names]
            ax.bar(x + k * width, values, width, label=agent)
        ax.set_xticks(x + 0.4 - width / 2, scenario_names, rotation=60, ha="right", fontsize=7)
        ax.set_ylim(0, 1)
        ax.set_ylabel(name)
        ax.set_title(f"{suite.name}: {name} per scenario")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(plots / f"metric_{name}.png", dpi=90)
        plt.close(fig)


def _trajectory_plots(plots: Path, suite: Suite, agents: list[str], results: list[dict]) -> None:
    """For each scenario: the road (lane centre lines) and every agent's first-episode paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from smarts.env.assembly import scenario_map

    for entry in suite.scenarios:
        road_map = scenario_map(entry.spec)
        fig, ax = plt.subplots(figsize=(5, 5))
        for lane in range(road_map.num_lanes):
            pts = road_map.lane_polyline(lane)
            ax.plot(pts[:, 0], pts[:, 1], color="0.8", linewidth=0.6, zorder=1)
        colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, agent in enumerate(agents):
            first = next((r for r in results if r["agent"] == agent and r.get("scenario") == entry.name
                          and r.get("episode") == 0 and r.get("log")), None)  # fmt: skip
            if first is None:
                continue
            log = read_episode(first["log"])
            for j, trace in enumerate(log.agents.values()):
                ax.plot(trace.x, trace.y, color=colours[k % len(colours)], linewidth=1.5,
                        label=agent if j == 0 else None, zorder=2)  # fmt: skip
                ax.plot(trace.x[:1], trace.y[:1], "o", color=colours[k % len(colours)], markersize=3)
        drawn = [line.get_xydata() for line in ax.lines[road_map.num_lanes :]]
        if drawn:  # frame the driven paths, not the whole map
            xy = np.concatenate(drawn)
            lo, hi = xy.min(axis=0) - 25.0, xy.max(axis=0) + 25.0
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(entry.name, fontsize=8)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(plots / f"trajectories_{entry.name}.png", dpi=80)
        plt.close(fig)


def _tensorboard(folder: Path, suite: Suite, scores: dict, names: tuple[str, ...], label) -> None:
    from torch.utils.tensorboard import SummaryWriter

    for agent, s in scores.items():
        if s is None:
            continue
        with SummaryWriter(log_dir=str(folder / label(agent))) as writer:
            for name in names:
                writer.add_scalar(f"{suite.name}/{name}", s.overall[name], 0)
            for k, entry in enumerate(suite.scenarios):
                row = s.scenarios.get(entry.name)
                if row is not None:
                    writer.add_scalar(f"{suite.name}/scenario_S_bench", row["S_bench"], k)
