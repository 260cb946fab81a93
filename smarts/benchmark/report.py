"""The benchmark report: results JSON/CSV, Markdown tables, plots and TensorBoard scalars.

Everything is computed from the episode logs on disk through ``smarts.benchmark.metrics``, so a
report can be rebuilt from a run folder alone. Every report lists the episodes with their seeds
(per scenario: episode index -> seed, and the failures), gives each agent's mean and confidence
interval for every metric, overall and per scenario (``score_suite``: stratified bootstrap), says
how the intervals were made, and shows the reference agents beside the requested ones.

Failed episodes (the agent raised, its worker process died twice, ...) are scored as the metrics
config's ``failed_episodes`` says and listed with their reasons; episodes that ran again after a
dead worker are listed too. A report of an interrupted run says how many episodes did not run.
``results.json``, ``results.csv`` and ``report.md`` are each replaced atomically.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from smarts.benchmark.metrics import load_params, read_episode, score_suite
from smarts.benchmark.metrics.scores import CI_LEVEL, CI_RESAMPLES, CI_SEED, ci_method, metric_names
from smarts.benchmark.suites import Suite
from smarts.files import atomic_write_text


def _cell(value: float, ci) -> str:
    return f"{value:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]" if ci else f"{value:.3f}"


def _seed_list(seeds: dict) -> str:
    return ", ".join(f"{e}={s}" for e, s in sorted(seeds.items()))


def write_report(
    out: Path,
    suite: Suite,
    agents: list[str],
    results: list[dict],
    *,
    ci_level: float = CI_LEVEL,
    resamples: int = CI_RESAMPLES,
    ci_seed: int = CI_SEED,
    not_run: int = 0,
) -> Path:
    """Score each agent's logs and write ``results.json``, ``results.csv``, ``report.md``,
    ``plots/`` and TensorBoard events under ``out``; returns the report path.

    ``agents`` are the requested agents; the reference agents found in ``results`` (added by
    ``plan_jobs``) are reported beside them. Intervals: ``score_suite``'s stratified bootstrap
    with ``ci_level``, ``resamples`` and ``ci_seed``. ``not_run``: planned episodes that did not
    run (an interrupted run); the report says so and ``results.json`` has ``complete: false``."""
    from smarts.benchmark.runner import REFERENCE_AGENTS, agent_label

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    params = load_params()
    names = metric_names(suite.task)
    agents = list(dict.fromkeys(agents))
    references = [a for a in REFERENCE_AGENTS if a not in agents and any(r["agent"] == a for r in results)]
    shown = agents + references
    scores = {}
    crashed = {}
    setup: dict[str, dict[str, Any]] = {}
    seeds: dict[str, dict[int, Any]] = {}  # scenario -> episode -> seed, over every job
    for agent in shown:
        mine = [r for r in results if r["agent"] == agent]
        logs = [read_episode(r["log"]) for r in mine if r.get("log")]
        crashed[agent] = [r for r in mine if not r.get("log")]
        if logs and params.failed_episodes == "exclude" and all(log.failed for log in logs):
            crashed[agent] = [r for r in mine if r.get("failure")]  # nothing to score: list them all
            logs = []
        scores[agent] = (
            score_suite(logs, params, ci_level=ci_level, resamples=resamples, ci_seed=ci_seed) if logs else None
        )
        info = next((log.info for log in logs if log.info.get("action_space")), {})
        first = next((r for r in mine if r.get("action_space")), {})
        setup[agent] = {
            "action_space": info.get("action_space") or first.get("action_space"),
            "controller": info.get("controller") or first.get("controller"),
            "interface": info.get("interface"),
        }
        for r in mine:
            if r.get("scenario") is not None and r.get("seed") is not None:
                seeds.setdefault(r["scenario"], {})[int(r["episode"])] = int(r["seed"])
        for log in logs:
            if log.seed is not None:
                seeds.setdefault(log.scenario, {})[int(log.episode)] = int(log.seed)
    order = [s.name for s in suite.scenarios]
    seeds = {name: dict(sorted(seeds[name].items())) for name in order if name in seeds}
    failures = [
        {"agent": a, "scenario": f.get("scenario"), "episode": f.get("episode"), "seed": f.get("seed"),
         "failure": f.get("failure")}
        for a in shown for f in ([*(scores[a].failed if scores[a] is not None else []), *crashed[a]])
    ]  # fmt: skip
    retried = [
        {"agent": r["agent"], "scenario": r.get("scenario"), "episode": r.get("episode"), "seed": r.get("seed"),
         "reasons": list(r["retried"])}
        for r in results if r.get("retried") and r["agent"] in shown
    ]  # fmt: skip
    method = ci_method(ci_level, resamples, ci_seed)

    doc = {
        "suite": suite.name,
        "task": suite.task,
        "complete": not_run == 0,
        "episodes_not_run": int(not_run),
        "action_spaces": list(suite.action_spaces),
        "scenarios": [{"name": s.name, "difficulty": s.difficulty, "time_limit": s.time_limit} for s in suite.scenarios],
        "seeds": {name: {str(e): sd for e, sd in eps.items()} for name, eps in seeds.items()},
        "failures": failures,
        "retried": retried,
        "ci": {"level": ci_level, "resamples": resamples, "seed": ci_seed, "method": method},
        "references": references,
        "agents": {
            agent: {
                "reference": agent in REFERENCE_AGENTS,
                **setup[agent],
                "scores": scores[agent].to_dict() if scores[agent] is not None else None,
                "crashed_episodes": crashed[agent],
            }
            for agent in shown
        },
    }
    atomic_write_text(out / "results.json", json.dumps(doc, indent=2, default=float))
    difficulty = {s.name: s.difficulty for s in suite.scenarios}
    with io.StringIO(newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["agent", "reference", "action_space", "controller", "scenario", "difficulty", "episodes",
                         "seeds", "failed", *(c for n in names for c in (n, f"{n}_ci_low", f"{n}_ci_high"))])  # fmt: skip
        for agent in shown:
            s = scores[agent]
            if s is None:
                continue
            head = [agent, agent in REFERENCE_AGENTS, setup[agent]["action_space"], setup[agent]["controller"]]
            n_failed = {}
            for fail in failures:
                if fail["agent"] == agent:
                    n_failed[fail["scenario"]] = n_failed.get(fail["scenario"], 0) + 1
            for scenario in [n for n in order if n in s.scenarios]:
                row, ci = s.scenarios[scenario], s.scenario_ci[scenario]
                writer.writerow([*head, scenario, difficulty.get(scenario, ""), s.episodes[scenario],
                                 _seed_list(seeds.get(scenario, {})).replace(", ", ";"), n_failed.get(scenario, 0),
                                 *(f"{v:.4f}" for n in names for v in (row[n], *ci[n]))])  # fmt: skip
            writer.writerow([*head, "overall", "", sum(s.episodes.values()), "", sum(n_failed.values()),
                             *(f"{v:.4f}" for n in names for v in (s.overall[n], *s.overall_ci[n]))])  # fmt: skip
        atomic_write_text(out / "results.csv", f.getvalue())

    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    _metric_plots(plots, suite, scores, names)
    _trajectory_plots(plots, suite, shown, results)
    _tensorboard(out / "tensorboard", suite, scores, names, agent_label)

    def label(agent: str) -> str:
        return f"{agent} (reference)" if agent in REFERENCE_AGENTS else agent

    episodes = sorted({n for eps in seeds.values() for n in [len(eps)]})
    first = sorted({min(eps.values()) for eps in seeds.values() if eps})
    lines = [f"# Benchmark: {suite.name} ({suite.task})", ""]
    if not_run:
        lines += [f"**Incomplete:** {not_run} planned episode(s) did not run (the run was interrupted); the "
                  "same command with `--resume` runs only those and rewrites this report.", ""]  # fmt: skip
    lines += [
        f"{len(suite.scenarios)} scenarios x {'/'.join(map(str, episodes)) or '0'} episodes; episode e of every "
        f"scenario runs with seed {first[0] if len(first) == 1 else 'see below'} + e (list below). Means over a "
        "scenario's episodes, then over scenarios (each scenario weighs the same). Brackets: " + method,
        "",
        "Reference agents (always run with the same suite, seeds and episodes): "
        + ", ".join(f"`{a}`" for a in REFERENCE_AGENTS) + "." + ("" if all(a in shown for a in REFERENCE_AGENTS)
                                                                  else " Missing from this run: "
                                                                  + ", ".join(a for a in REFERENCE_AGENTS if a not in shown) + "."),
        "",
    ]  # fmt: skip
    lines += ["| method | action space | controller | " + " | ".join(names) + " |",
              "|---|---|---|" + "---:|" * len(names)]  # fmt: skip
    for agent in shown:
        s = scores[agent]
        cells = " | ".join(_cell(s.overall[n], s.overall_ci.get(n)) if s else "n/a" for n in names)
        lines.append(f"| {label(agent)} | {setup[agent]['action_space']} | {setup[agent]['controller']} | {cells} |")
    lines += ["", "## Per scenario", ""]
    for entry in suite.scenarios:
        lines += [f"### {entry.name} ({entry.difficulty}, {entry.time_limit:g} s; episodes {_seed_list(seeds.get(entry.name, {}))})", ""]
        lines += ["| method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
        for agent in shown:
            s = scores[agent]
            row = s.scenarios.get(entry.name) if s is not None else None
            ci = s.scenario_ci.get(entry.name, {}) if s is not None else {}
            cells = " | ".join(_cell(row[n], ci.get(n)) if row else "n/a" for n in names)
            lines.append(f"| {label(agent)} | {cells} |")
        lines.append("")
    lines += ["## Episodes and seeds", "", "| scenario | difficulty | time limit (s) | episode=seed | failed episodes |",
              "|---|---|---:|---|---|"]  # fmt: skip
    for entry in suite.scenarios:
        mine = [f for f in failures if f["scenario"] == entry.name]
        failed = "; ".join(f"{f['agent']} #{f['episode']}" for f in mine) or "none"
        lines.append(f"| {entry.name} | {entry.difficulty} | {entry.time_limit:g} | {_seed_list(seeds.get(entry.name, {}))} | {failed} |")
    if failures:
        lines += ["", "## Failed episodes", ""]
        lines += [f"- {f['agent']}: {f['scenario'] or '?'} #{f['episode']} (seed {f['seed']}): {f['failure']}" for f in failures]
    if retried:
        lines += ["", "## Episodes run again after their worker process died", ""]
        lines += [f"- {r['agent']}: {r['scenario'] or '?'} #{r['episode']} (seed {r['seed']}): {'; '.join(r['reasons'])}"
                  for r in retried]  # fmt: skip
    lines += ["", "Plots: `plots/`; TensorBoard: `tensorboard --logdir " + str(out / "tensorboard") + "`."]
    report = out / "report.md"
    atomic_write_text(report, "\n".join(lines) + "\n")
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
            sc = scores[agent]
            values = np.array([sc.scenarios.get(s, {}).get(name, np.nan) for s in scenario_names])
            ci = np.array([sc.scenario_ci.get(s, {}).get(name, (np.nan, np.nan)) for s in scenario_names])
            yerr = np.nan_to_num(np.abs(np.stack([values - ci[:, 0], ci[:, 1] - values])))
            ax.bar(x + k * width, values, width, yerr=yerr, capsize=1.5, label=agent)
        ax.set_xticks(x + 0.4 - width / 2, scenario_names, rotation=60, ha="right", fontsize=7)
        ax.set_ylim(0, 1)
        ax.set_ylabel(name)
        ax.set_title(f"{suite.name}: {name} per scenario")
        if ax.get_legend_handles_labels()[0]:  # none when no agent has a finished episode
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
        if ax.get_legend_handles_labels()[0]:  # none when nothing of this scenario finished
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
