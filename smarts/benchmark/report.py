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

An interval of zero width (one episode per scenario, or episodes that all scored alike) says
nothing about uncertainty, so it is never printed as one: ``report.md`` shows ``n/a`` with a
warning, ``results.csv`` leaves its cells empty and ``results.json`` has ``null``.

Figures, all embedded in ``report.md`` (paths relative to it, so the folder can be moved):

- ``plots/metric_<M>.png``: metric M per scenario and overall, one bar per agent with its
  confidence interval, the stand-still agent's value drawn across each group as the floor a
  policy must beat (doing nothing scores well on RC and Humanness), the legend beside the axes.
- ``plots/trajectories_<scenario>.png``: the road around where the episode happened (lane
  surfaces, edges and dividers, junctions; axes in metres), each agent's path in episode 0 with
  its start and end, and, from the first agent's episode log, the lead vehicle's path and the
  other road users' paths (``EpisodeLog.scene``).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smarts.benchmark.metrics import load_params, read_episode, score_episode, score_suite
from smarts.benchmark.metrics.scores import CI_LEVEL, CI_RESAMPLES, CI_SEED, ci_method, metric_names
from smarts.benchmark.suites import Suite
from smarts.files import atomic_write_bytes, atomic_write_text

_log = logging.getLogger(__name__)

PREFETCH_BYTES = 128 * 2**20
"""Log files a :class:`ReportAhead` keeps read ahead at most (about four thousand episodes)."""
ZERO_WIDTH = 1e-12
"""An interval narrower than this has no spread behind it and is shown as n/a."""
NA_REASON = (
    "the episodes behind the value show no spread (one episode per scenario, or every episode scored "
    "alike), so no interval can be given; run more episodes (--episodes 5 or more) before reading differences"
)


def has_spread(ci) -> bool:
    """Whether an interval ``(low, high)`` is one to print (it has a width)."""
    return bool(ci) and ci[1] - ci[0] > ZERO_WIDTH


def _cell(value: float, ci) -> str:
    if not ci:
        return f"{value:.3f}"
    return f"{value:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]" if has_spread(ci) else f"{value:.3f} [n/a]"


def _ci_or_null(ci):
    return list(ci) if has_spread(ci) else None


def _honest(scores: dict | None) -> dict | None:
    """``SuiteScores.to_dict()`` with zero-width intervals as None (JSON null)."""
    if scores is None:
        return None
    out = dict(scores)
    out["overall_ci"] = {m: _ci_or_null(ci) for m, ci in scores["overall_ci"].items()}
    out["scenario_ci"] = {n: {m: _ci_or_null(ci) for m, ci in cis.items()} for n, cis in scores["scenario_ci"].items()}
    return out


def _seed_list(seeds: dict) -> str:
    return ", ".join(f"{e}={s}" for e, s in sorted(seeds.items()))


@dataclass
class _Scored:
    """Every agent's scores and what the report says about its episodes."""

    shown: list[str]  # the requested agents, then the references found in the results
    references: list[str]
    names: tuple[str, ...]  # the task's metrics
    scores: dict[str, Any]  # agent -> SuiteScores, None when no episode was scored
    crashed: dict[str, list[dict]]  # agent -> summaries of episodes without a log
    setup: dict[str, dict[str, Any]]  # agent -> action space, controller, interface
    seeds: dict[str, dict[int, int]]  # scenario -> episode -> seed, in the suite's order
    failures: list[dict]
    retried: list[dict]
    method: str  # how the intervals were made


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
    helpers: FigureHelpers | None = None,
    ahead: ReportAhead | None = None,
) -> Path:
    """Score each agent's logs and write ``results.json``, ``results.csv``, ``report.md``,
    ``plots/`` and TensorBoard events under ``out``; returns the report path.

    ``agents`` are the requested agents; the reference agents found in ``results`` (added by
    ``plan_jobs``) are reported beside them. Intervals: ``score_suite``'s stratified bootstrap
    with ``ci_level``, ``resamples`` and ``ci_seed``. ``not_run``: planned episodes that did not
    run (an interrupted run); the report says so and ``results.json`` has ``complete: false``.
    ``helpers``: figure helpers started ahead (:class:`FigureHelpers`), else they start here.
    ``ahead``: the report as prepared while the episodes ran (:class:`ReportAhead`: logs read,
    trajectory figures handed to its helpers); the figures it did not draw are drawn here."""
    from smarts.benchmark.agents import agent_label

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    agents = list(dict.fromkeys(agents))
    label = _label
    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    # Drawn beside the scoring (from the logs alone, so they can start first); the metric figures
    # join them once the scores are known.
    figures = _trajectory_figures(plots, suite, _shown(agents, results)[0], results)
    drawing = ahead.drawing_for(figures, helpers) if ahead is not None else _Drawing(figures, helpers)
    try:
        scored = _score(suite, agents, results, ci_level, resamples, ci_seed, ahead or _Reading())
        atomic_write_text(
            out / "results.json",
            json.dumps(_results_doc(suite, scored, not_run, ci_level, resamples, ci_seed), indent=2, default=float),
        )
        atomic_write_text(out / "results.csv", _results_csv(suite, scored))
        drawing.add(_metric_figures(plots, suite, scored.scores, scored.names, label))
        _tensorboard(out / "tensorboard", suite, scored.scores, scored.names, agent_label)
    except BaseException:
        drawing.cancel()
        raise
    drawn = drawing.result()
    metric_figures = {key[1]: path for key, path in drawn.items() if isinstance(key, tuple)}
    trajectory_figures = {key: path for key, path in drawn.items() if not isinstance(key, tuple)}
    lines = _summary_lines(suite, scored, not_run, label)
    lines += _figure_lines(metric_figures)
    lines += _scenario_lines(suite, scored, trajectory_figures, label)
    lines += _episode_lines(suite, scored, out)
    report = out / "report.md"
    atomic_write_text(report, "\n".join(lines) + "\n")
    return report


BACKGROUND_NICE = 10
"""How much lower than the run's the priority of the work done beside its episodes is (reading
logs ahead, drawing figures): on a machine whose cores the workers fill, it waits for them instead
of slowing the slowest one, and it takes the cores they leave as they finish."""


def _lower_priority() -> None:
    """Lower the calling thread's priority by :data:`BACKGROUND_NICE` (Linux: per thread), where allowed."""
    import os

    with contextlib.suppress(AttributeError, OSError):
        os.nice(BACKGROUND_NICE)


def _label(agent: str) -> str:
    """How the report names an agent: its name, and "(reference)" for the reference agents."""
    from smarts.benchmark.agents import REFERENCE_AGENTS, agent_name

    return f"{agent_name(agent)} (reference)" if agent in REFERENCE_AGENTS else agent_name(agent)


class _Reading:
    """How a report reads and scores its logs: from the files, as it goes (:class:`ReportAhead`
    does it ahead)."""

    def read(self, path: str | Path):
        return read_episode(path)

    def score(self, log, params) -> dict[str, float]:
        return score_episode(log, params)


class ReportAhead(_Reading):
    """A benchmark report prepared while its episodes run, in the process that only waits for its
    workers meanwhile: the logs are read and scored as their episodes finish (a report otherwise
    starts by reading back and scoring every log, about 5 ms each, and importing pyplot, half a second), and a
    scenario's trajectory figure goes to the figure helpers as soon as every agent's episode 0 of
    it has finished, so they draw it on a core the last episodes leave free.

    Give :meth:`offer` to ``run_jobs`` (its ``on_result``) and this to :func:`write_report`.
    The report reads and scores the logs through :meth:`read` and :meth:`score`, which take what
    was done ahead and do the rest then, so it scores the files on disk exactly as without it
    (with the shipped metric parameters; others are scored then); it builds its figures as it
    always does and draws only those not handed out already (a figure handed out that differs
    from the report's is drawn again after). At most ``budget`` bytes of log files are kept
    ahead (about twice that in memory); later logs are read when the report needs them."""

    def __init__(self, out: str | Path, suite: Suite, agents: list[str], jobs: list, helpers: FigureHelpers | None = None,
                 budget: int = PREFETCH_BYTES):  # fmt: skip
        import queue
        import threading

        self.budget = budget
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._logs: dict[str, tuple[int, Any]] = {}  # path -> (the offer it was read for, log)
        self._offers: dict[str, int] = {}  # path -> how often it was offered (a re-run offers it again)
        self._scores: dict[int, tuple[Any, Any, dict[str, float]]] = {}  # id(log) -> (log, params, scores)
        self._enough = False  # set when the report starts: the thread stops after the log in hand
        self._thread = threading.Thread(target=self._read_ahead, name="report-ahead", daemon=True)
        # The report's rule, over the planned episodes: by the end each has a result.
        self.shown = _shown(list(dict.fromkeys(agents)), [{"agent": job.agent} for job in jobs])[0]
        self.plots, self.suite = Path(out) / "plots", suite
        names = [entry.name for entry in suite.scenarios]
        self._waiting = {name: {j.agent for j in jobs if j.episode == 0 and names[j.scenario_index] == name}
                         for name in names}  # fmt: skip
        self._first: dict[str, list[dict]] = {name: [] for name in names}
        self.handed: list[_TrajectoryFigure] = []
        self.drawing = _Drawing([], helpers) if helpers is not None and helpers.processes else None
        self._thread.start()

    def offer(self, summary: dict) -> None:
        """A finished episode's summary (``run_jobs``'s ``on_result``)."""
        if summary.get("log") and self.budget > 0:
            path = str(summary["log"])
            self._offers[path] = offer = self._offers.get(path, 0) + 1
            self._queue.put((path, offer))
        scenario = summary.get("scenario")
        if self.drawing is None or summary.get("episode") != 0 or scenario not in self._waiting:
            return
        waiting = self._waiting[scenario]
        waiting.discard(summary.get("agent"))
        self._first[scenario].append(summary)
        if not waiting:
            del self._waiting[scenario]
            entry = next(e for e in self.suite.scenarios if e.name == scenario)
            figure = _trajectory_figure_job(self.plots, self.suite.name, entry, self.shown, self._first[scenario])
            if figure is not None:
                self.plots.mkdir(parents=True, exist_ok=True)
                self.drawing.add([figure])
                self.handed.append(figure)

    def _read_ahead(self) -> None:
        import os

        _lower_priority()  # this thread only: the workers' episodes come first
        if self.drawing is None or self.drawing.caller_draws:
            with contextlib.suppress(Exception):  # the report imports them again and says what is wrong
                prepare_drawing()  # for the trajectory figures drawn here
        params = None
        while (item := self._queue.get()) is not None and not self._enough:
            path, offer = item
            try:
                size = os.path.getsize(path)
                if size > self.budget:
                    continue
                log = read_episode(path)  # a path offered again (a re-run) is read again
                self._logs[path] = (offer, log)
                self.budget -= size
                params = load_params() if params is None else params
                self._scores[id(log)] = (log, params, score_episode(log, params))
            except Exception:  # noqa: BLE001 - the report reads it again and says what is wrong
                self._logs.pop(path, None)

    def read(self, path: str | Path):
        """The episode log at ``path``: read ahead, else read now (raising what ``read_episode`` raises).
        The first call stops the reading ahead after the log in hand: what is left is read here, at
        the report's priority, not by the low-priority thread while the report waits for it."""
        if self._thread.is_alive():
            self._enough = True
            self._queue.put(None)
            self._thread.join()
        offer, log = self._logs.pop(str(path), (None, None))
        # A log read for an earlier offer of its path is stale: its episode ran again and the
        # thread stopped before reading the new file.
        return log if log is not None and offer == self._offers.get(str(path)) else read_episode(path)

    def score(self, log, params) -> dict[str, float]:
        """``score_episode(log, params)``: as computed ahead for a log :meth:`read` gave, else now."""
        ahead = self._scores.pop(id(log), None)
        if ahead is not None and ahead[0] is log and ahead[1] == params:
            return ahead[2]
        return score_episode(log, params)

    def drawing_for(self, figures: list[_TrajectoryFigure], helpers: FigureHelpers | None = None) -> _Drawing:
        """The drawing of a report's trajectory figures: those handed out already and the rest
        (with ``helpers`` when none were handed out)."""
        if self.drawing is None:
            return _Drawing(figures, helpers)
        keys = [h.key for h in self.handed]
        self.drawing.add([f for f in figures if f.key not in keys])
        self.drawing.redraw = [f for f in figures if f.key in keys and f not in self.handed]
        return self.drawing

    def cancel(self) -> None:
        """Stop the helpers (the run failed or was interrupted; the report draws its figures itself)."""
        if self.drawing is not None:
            self.drawing.cancel()
            self.drawing = None


def _shown(agents: list[str], results: list[dict]) -> tuple[list[str], list[str]]:
    """(the agents a report shows, the references among them): the requested agents, then the
    reference agents that have results."""
    from smarts.benchmark.agents import REFERENCE_AGENTS

    references = [a for a in REFERENCE_AGENTS if a not in agents and any(r["agent"] == a for r in results)]
    return agents + references, references


def _score(
    suite: Suite,
    agents: list[str],
    results: list[dict],
    ci_level: float,
    resamples: int,
    ci_seed: int,
    reading: _Reading | None = None,
) -> _Scored:
    """Each agent's logs read and scored (by ``reading``); seeds, failures and re-runs gathered from
    the results."""
    params, reading = load_params(), reading or _Reading()
    shown, references = _shown(agents, results)
    scores, crashed, setup = {}, {}, {}
    seeds: dict[str, dict[int, Any]] = {}  # scenario -> episode -> seed, over every job
    for agent in shown:
        mine = [r for r in results if r["agent"] == agent]
        logs = [reading.read(r["log"]) for r in mine if r.get("log")]
        crashed[agent] = [r for r in mine if not r.get("log")]
        if logs and params.failed_episodes == "exclude" and all(log.failed for log in logs):
            crashed[agent] = [r for r in mine if r.get("failure")]  # nothing to score: list them all
            logs = []
        scores[agent] = (
            score_suite(logs, params, ci_level=ci_level, resamples=resamples, ci_seed=ci_seed, score=reading.score)
            if logs
            else None
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
    return _Scored(
        shown=shown, references=references, names=metric_names(suite.task), scores=scores, crashed=crashed,
        setup=setup, seeds={name: dict(sorted(seeds[name].items())) for name in order if name in seeds},
        failures=failures, retried=retried, method=ci_method(ci_level, resamples, ci_seed),
    )  # fmt: skip


def _results_doc(suite: Suite, sc: _Scored, not_run: int, ci_level: float, resamples: int, ci_seed: int) -> dict:
    """``results.json``'s content."""
    from smarts.benchmark.agents import REFERENCE_AGENTS, agent_name

    return {
        "suite": suite.name,
        "task": suite.task,
        "complete": not_run == 0,
        "episodes_not_run": int(not_run),
        "action_spaces": list(suite.action_spaces),
        "scenarios": [
            {"name": s.name, "difficulty": s.difficulty, "time_limit": s.time_limit} for s in suite.scenarios
        ],
        "seeds": {name: {str(e): sd for e, sd in eps.items()} for name, eps in sc.seeds.items()},
        "failures": sc.failures,
        "retried": sc.retried,
        "ci": {
            "level": ci_level,
            "resamples": resamples,
            "seed": ci_seed,
            "method": sc.method,
            "null": f"an interval is null where {NA_REASON}",
        },
        "references": sc.references,
        "agents": {
            agent: {
                "name": agent_name(agent),
                "reference": agent in REFERENCE_AGENTS,
                **sc.setup[agent],
                "scores": _honest(sc.scores[agent].to_dict()) if sc.scores[agent] is not None else None,
                "crashed_episodes": sc.crashed[agent],
            }
            for agent in sc.shown
        },
    }


def _results_csv(suite: Suite, sc: _Scored) -> str:
    """``results.csv``: a row per agent and scenario, then its overall row."""
    from smarts.benchmark.agents import REFERENCE_AGENTS

    names, order = sc.names, [s.name for s in suite.scenarios]
    difficulty = {s.name: s.difficulty for s in suite.scenarios}
    with io.StringIO(newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["agent", "reference", "action_space", "controller", "scenario", "difficulty", "episodes",
                         "seeds", "failed", *(c for n in names for c in (n, f"{n}_ci_low", f"{n}_ci_high"))])  # fmt: skip
        for agent in sc.shown:
            s = sc.scores[agent]
            if s is None:
                continue
            head = [agent, agent in REFERENCE_AGENTS, sc.setup[agent]["action_space"], sc.setup[agent]["controller"]]
            n_failed = {}
            for fail in sc.failures:
                if fail["agent"] == agent:
                    n_failed[fail["scenario"]] = n_failed.get(fail["scenario"], 0) + 1
            for scenario in [n for n in order if n in s.scenarios]:
                row, ci = s.scenarios[scenario], s.scenario_ci[scenario]
                writer.writerow([*head, scenario, difficulty.get(scenario, ""), s.episodes[scenario],
                                 _seed_list(sc.seeds.get(scenario, {})).replace(", ", ";"), n_failed.get(scenario, 0),
                                 *(c for n in names for c in _csv_cells(row[n], ci[n]))])  # fmt: skip
            writer.writerow([*head, "overall", "", sum(s.episodes.values()), "", sum(n_failed.values()),
                             *(c for n in names for c in _csv_cells(s.overall[n], s.overall_ci[n]))])  # fmt: skip
        return f.getvalue()


def _summary_lines(suite: Suite, sc: _Scored, not_run: int, label) -> list[str]:
    """The report's head: what ran, how intervals were made, the references, the overall table."""
    from smarts.benchmark.agents import REFERENCE_AGENTS

    names, shown = sc.names, sc.shown
    no_spread = _no_spread(sc)
    episodes = sorted({n for eps in sc.seeds.values() for n in [len(eps)]})
    first = sorted({min(eps.values()) for eps in sc.seeds.values() if eps})
    lines = [f"# Benchmark: {suite.name} ({suite.task})", ""]
    if not_run:
        lines += [f"**Incomplete:** {not_run} planned episode(s) did not run (the run was interrupted); the "
                  "same command with `--resume` runs only those and rewrites this report.", ""]  # fmt: skip
    lines += [
        f"{len(suite.scenarios)} scenarios x {'/'.join(map(str, episodes)) or '0'} episodes; episode e of every "
        f"scenario runs with seed {first[0] if len(first) == 1 else 'see below'} + e (list below). Means over a "
        "scenario's episodes, then over scenarios (each scenario weighs the same). Brackets: " + sc.method,
        "",
        "Reference agents (always run with the same suite, seeds and episodes): "
        + ", ".join(f"`{a}`" for a in REFERENCE_AGENTS) + "." + ("" if all(a in shown for a in REFERENCE_AGENTS)
                                                                  else " Missing from this run: "
                                                                  + ", ".join(a for a in REFERENCE_AGENTS if a not in shown) + "."),
        "",
    ]  # fmt: skip
    if no_spread:
        lines += [f"**Warning:** some intervals below are n/a: {NA_REASON}.", ""]
    lines += ["| method | action space | controller | " + " | ".join(names) + " |",
              "|---|---|---|" + "---:|" * len(names)]  # fmt: skip
    for agent in shown:
        s = sc.scores[agent]
        cells = " | ".join(_cell(s.overall[n], s.overall_ci.get(n)) if s else "no episode scored" for n in names)
        setup = sc.setup[agent]
        lines.append(
            f"| {label(agent)} | {setup['action_space'] or 'unknown'} | {setup['controller'] or 'unknown'} | {cells} |"
        )
    lines += _all_failed_lines(sc, label)
    if no_spread:
        lines += ["", f"n/a: {NA_REASON}."]
    return lines


def _all_failed_lines(sc: _Scored, label) -> list[str]:
    """A warning under the table for each agent none of whose episodes ran to a score: its row is
    the score the suite gives failures, not its driving (e.g. a policy that could not be loaded)."""
    planned = sum(len(episodes) for episodes in sc.seeds.values())
    lines = []
    for agent in sc.shown:
        reasons = [f["failure"] for f in sc.failures if f["agent"] == agent]
        if planned and len(reasons) >= planned:
            first = next((r for r in reasons if r), "no reason recorded")
            others = len(set(reasons)) - 1
            lines += ["", f"**Every episode of {label(agent)} failed**, so its row scores failures, not driving. "
                          f"Reason: {first}" + (f" (and {others} other reason(s), listed below)" if others else "")
                          + "."]  # fmt: skip
    return lines


def _no_spread(sc: _Scored) -> bool:
    return any(
        not has_spread(ci)
        for s in sc.scores.values() if s is not None
        for cis in [s.overall_ci, *s.scenario_ci.values()] for ci in cis.values()
    )  # fmt: skip


def _figure_lines(metric_figures: dict[str, Path]) -> list[str]:
    if not metric_figures:
        return []
    lines = ["", "## Metrics per scenario", "",
             "Bars: each agent's mean, overall (left) and per scenario, with its confidence interval (none "
             "where n/a). Dashed line: the stand-still agent's value, the floor a policy has to beat.", ""]  # fmt: skip
    for name, path in metric_figures.items():
        lines += [f"![{name} per scenario](plots/{path.name})", ""]
    return lines


def _scenario_lines(suite: Suite, sc: _Scored, trajectory_figures: dict[str, Path], label) -> list[str]:
    """A table per scenario, its trajectory figure under it."""
    names = sc.names
    lines = ["", "## Per scenario", ""]
    for entry in suite.scenarios:
        lines += [
            f"### {entry.name} ({entry.difficulty}, {entry.time_limit:g} s; episodes {_seed_list(sc.seeds.get(entry.name, {}))})",
            "",
        ]
        lines += ["| method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
        for agent in sc.shown:
            s = sc.scores[agent]
            row = s.scenarios.get(entry.name) if s is not None else None
            ci = s.scenario_ci.get(entry.name, {}) if s is not None else {}
            cells = " | ".join(_cell(row[n], ci.get(n)) if row else "no episode scored" for n in names)
            lines.append(f"| {label(agent)} | {cells} |")
        if entry.name in trajectory_figures:
            lines += ["", f"![{entry.name}: paths of episode 0](plots/{trajectory_figures[entry.name].name})"]
        lines.append("")
    return lines


def _episode_lines(suite: Suite, sc: _Scored, out: Path) -> list[str]:
    """The seeds of every episode, the failed and re-run ones, where the logs are."""
    lines = ["## Episodes and seeds", "", "| scenario | difficulty | time limit (s) | episode=seed | failed episodes |",
             "|---|---|---:|---|---|"]  # fmt: skip
    for entry in suite.scenarios:
        mine = [f for f in sc.failures if f["scenario"] == entry.name]
        failed = "; ".join(f"{f['agent']} #{f['episode']}" for f in mine) or "none"
        lines.append(
            f"| {entry.name} | {entry.difficulty} | {entry.time_limit:g} | {_seed_list(sc.seeds.get(entry.name, {}))} | {failed} |"
        )
    if sc.failures:
        lines += ["", "## Failed episodes", ""]
        lines += [
            f"- {f['agent']}: {f['scenario'] or '?'} #{f['episode']} (seed {f['seed']}): {f['failure']}"
            for f in sc.failures
        ]
    if sc.retried:
        lines += ["", "## Episodes run again after their worker process died", ""]
        lines += [f"- {r['agent']}: {r['scenario'] or '?'} #{r['episode']} (seed {r['seed']}): {'; '.join(r['reasons'])}"
                  for r in sc.retried]  # fmt: skip
    lines += ["", "Episode logs: `logs/` (`smarts viz " + str(out / "logs") + "` replays them with the lead and "
              "traffic); TensorBoard: `tensorboard --logdir " + str(out / "tensorboard") + "`."]  # fmt: skip
    return lines


def _csv_cells(value: float, ci) -> list[str]:
    """A value and its interval for the CSV; the interval's cells empty when it has no spread."""
    return [f"{value:.4f}", *((f"{ci[0]:.4f}", f"{ci[1]:.4f}") if has_spread(ci) else ("", ""))]


REFERENCE_COLOURS = {"zoo:keep-lane": "#7a68b8", "zoo:random": "#d9a21b", "zoo:stand-still": "#9a9a9a"}
"""The references' colours, the same in every report (the requested agents take the others)."""
AGENT_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#17becf", "#e377c2", "#8c564b", "#bcbd22")
FLOOR_AGENT = "zoo:stand-still"
TRAFFIC_COLOUR = "#5b8fd6"


def _colours(agents: list[str]) -> dict[str, str]:
    """One colour per agent, the same in every figure."""
    out, k = {}, 0
    for agent in agents:
        if agent in REFERENCE_COLOURS:
            out[agent] = REFERENCE_COLOURS[agent]
        else:
            out[agent] = AGENT_COLOURS[k % len(AGENT_COLOURS)]
            k += 1
    return out


SPARE_INCHES = (1.5, 6.0, 3.5, 1.0)
"""Canvas added left, right, below and above a figure before it is drawn, so what sticks out of it
(a legend beside the axes, slanted scenario names) is drawn on the canvas and cropped to after."""
PAD_INCHES = 0.1  # around what was drawn, as ``bbox_inches="tight"`` pads


def _save(fig, path: Path, dpi: int = 100) -> Path:
    """A figure as PNG through the one atomic write (readable by others, never half written),
    cropped to what was drawn, padded as ``savefig(bbox_inches="tight")`` pads, but from a single
    rendering: "tight" lays the figure out twice, about a third of a report figure's cost. The
    figure is drawn on a canvas grown by :data:`SPARE_INCHES` (the axes where they were), and the
    pixels that differ from the figure's background, padded, are encoded (RGB: the figure is
    opaque); should anything reach the canvas's edge, it is saved the two-pass way."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import to_rgba
    from PIL import Image

    width, height = fig.get_size_inches()
    left, right, below, above = SPARE_INCHES
    grown_w, grown_h = width + left + right, height + below + above
    for ax in fig.axes:
        box = ax.get_position()
        ax.set_position([(box.x0 * width + left) / grown_w, (box.y0 * height + below) / grown_h,
                         box.width * width / grown_w, box.height * height / grown_h])  # fmt: skip
    fig.set_size_inches(grown_w, grown_h)
    fig.set_dpi(dpi)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    pixels = np.asarray(canvas.buffer_rgba())
    background = np.array([round(255 * c) for c in to_rgba(fig.get_facecolor())], dtype=np.uint8)
    ink = pixels.view(np.uint32)[..., 0] != background.view(np.uint32)[0]
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    buffer = io.BytesIO()
    if not len(rows) or rows[0] == 0 or cols[0] == 0 or rows[-1] == ink.shape[0] - 1 or cols[-1] == ink.shape[1] - 1:
        fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    else:
        pad = round(PAD_INCHES * dpi)
        y0, y1 = max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, ink.shape[0])
        x0, x1 = max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, ink.shape[1])
        Image.fromarray(np.ascontiguousarray(pixels[y0:y1, x0:x1, :3])).save(buffer, format="png", compress_level=3)
    return atomic_write_bytes(path, buffer.getvalue())


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def prepare_drawing() -> None:
    """Import what drawing a report's figures takes (about a second): pyplot, the maps, the renderer."""
    _pyplot()
    import smarts.env.assembly  # noqa: F401 - the maps, for the roads
    import smarts.replay.render  # noqa: F401


@dataclass(frozen=True)
class _MetricFigure:
    """What one metric's figure needs, as plain data (it may be drawn in another process): per
    agent in legend order its name, colour, values and intervals over ``groups`` (overall, then
    the scenarios), and the stand-still floor's values."""

    plots: Path
    suite: str
    name: str
    groups: tuple[str, ...]
    bars: tuple[tuple[str, str, tuple[float, ...], tuple[Any, ...]], ...]  # (legend name, colour, values, intervals)
    floor: tuple[float, ...] | None

    @property
    def key(self) -> tuple[str, str]:
        return ("metric", self.name)


def _metric_figures(plots: Path, suite: Suite, scores: dict, names: tuple[str, ...], label) -> list[_MetricFigure]:
    """One figure per metric (see :func:`_metric_figure`), as jobs for :class:`_Drawing`."""
    agents = [a for a, s in scores.items() if s is not None]
    if not agents:
        return []
    colours = _colours(list(scores))
    groups = ("overall", *(s.name for s in suite.scenarios))
    floor = scores.get(FLOOR_AGENT)

    def values(sc, name: str) -> tuple[float, ...]:
        return (float(sc.overall[name]), *(float(sc.scenarios.get(g, {}).get(name, np.nan)) for g in groups[1:]))

    def intervals(sc, name: str) -> tuple:
        return (sc.overall_ci.get(name), *(sc.scenario_ci.get(g, {}).get(name) for g in groups[1:]))

    return [
        _MetricFigure(plots, suite.name, name, groups,
                      tuple((label(a), colours[a], values(scores[a], name), intervals(scores[a], name)) for a in agents),
                      values(floor, name) if floor is not None else None)
        for name in names
    ]  # fmt: skip


def _metric_figure(job: _MetricFigure) -> Path:
    """One metric overall and per scenario: a bar per agent with its interval, the stand-still
    floor across each group, the legend beside the axes."""
    plt = _pyplot()
    groups, name = job.groups, job.name
    x = np.arange(len(groups), dtype=float)
    width = 0.8 / len(job.bars)
    fig, ax = plt.subplots(figsize=(max(7.0, 0.22 * len(groups) * len(job.bars) + 3.0), 4.2))
    for k, (legend, colour, values, cis) in enumerate(job.bars):
        values = np.array(values)
        low = np.array([v - ci[0] if has_spread(ci) else 0.0 for v, ci in zip(values, cis)])
        high = np.array([ci[1] - v if has_spread(ci) else 0.0 for v, ci in zip(values, cis)])
        at = x - 0.4 + (k + 0.5) * width
        ax.bar(at, values, width * 0.92, color=colour, label=legend, zorder=2)
        spread = np.array([has_spread(ci) for ci in cis]) & np.isfinite(values)
        if spread.any():  # no error bar at all where the interval is n/a
            ax.errorbar(at[spread], values[spread], yerr=np.stack([low[spread], high[spread]]), fmt="none",
                        ecolor="black", elinewidth=0.9, capsize=2, zorder=3)  # fmt: skip
    if job.floor is not None:
        ax.hlines(list(job.floor), x - 0.45, x + 0.45, colors="black", linestyles="--", linewidth=1.1, zorder=3,
                  label="stand-still (the floor)")  # fmt: skip
    ax.axvline(0.5, color="0.6", linewidth=0.8)
    ax.set_xticks(x, list(groups), rotation=40, ha="right", fontsize=8)
    ax.get_xticklabels()[0].set_fontweight("bold")
    ax.set_xlim(-0.6, len(groups) - 0.4)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel(f"{name} (higher is better)")
    ax.grid(axis="y", color="0.9", zorder=0)
    ax.set_title(f"{job.suite}: {name}, overall and per scenario (bars: mean and confidence interval)", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    path = _save(fig, job.plots / f"metric_{name}.png")
    plt.close(fig)
    return path


def _tracks(scene) -> dict[int, np.ndarray]:
    """Road user index -> its positions [n, 2] over the scene's rows, in time order."""
    row = np.repeat(np.arange(scene.num_rows), np.diff(scene.offsets))
    order = np.lexsort((row, scene.index))
    index = scene.index[order]
    xy = np.stack([scene.x[order], scene.y[order]], axis=1).astype(np.float64)
    cuts = np.flatnonzero(np.diff(index)) + 1
    return {int(index[piece[0]]): xy[piece] for piece in np.split(np.arange(len(index)), cuts) if len(piece)}


STRETCH_ASPECT = 3.0
"""A crop longer than this many times its width (a long straight road) is drawn stretched across
(axes in metres, not to scale) instead of as a thin strip."""


def _crop(points: np.ndarray, margin: float = 12.0, least: float = 60.0) -> tuple[tuple[float, ...], bool]:
    """``((xmin, xmax, ymin, ymax), to_scale)`` around ``points``: a margin, at least ``least``
    metres along the longer side (a junction's arms stay in view). Where the result is flatter
    than :data:`STRETCH_ASPECT` the short side keeps only the margin and the picture is stretched
    across it (``to_scale`` False); otherwise the short side is padded so the picture is at most
    that flat and drawn to scale."""
    lo, hi = points.min(axis=0) - margin, points.max(axis=0) + margin
    centre, span = (lo + hi) / 2, hi - lo
    long = int(np.argmax(span))
    span[long] = max(span[long], least)
    to_scale = span[long] <= STRETCH_ASPECT * span[1 - long] or span[long] <= 2 * least
    if to_scale:
        span[1 - long] = max(span[1 - long], span[long] / STRETCH_ASPECT, least / 2)
    box = (centre[0] - span[0] / 2, centre[0] + span[0] / 2, centre[1] - span[1] / 2, centre[1] + span[1] / 2)
    return box, bool(to_scale)


def _draw_road(ax, road_map, box) -> None:
    """Lane surfaces, junctions, road edges (solid) and lane dividers (dashed) inside ``box``."""
    from matplotlib.collections import LineCollection, PolyCollection

    from smarts.replay.render import EDGE, Scene

    scene = Scene(None, road_map)
    xmin, xmax, ymin, ymax = box

    def inside(poly: np.ndarray) -> bool:
        if not len(poly):
            return False
        return (
            poly[:, 0].max() >= xmin
            and poly[:, 0].min() <= xmax
            and poly[:, 1].max() >= ymin
            and poly[:, 1].min() <= ymax
        )

    surfaces = [np.asarray(p) for p in scene.surfaces if len(p) >= 3 and inside(np.asarray(p))]
    ax.add_collection(PolyCollection(surfaces, facecolors="#d5d5d8", edgecolors="#d5d5d8", linewidths=0.3, zorder=0))
    edges = [np.asarray(line) for line, colour, dashed in scene.lines if colour == EDGE and inside(np.asarray(line))]
    dividers = [np.asarray(line) for line, colour, dashed in scene.lines if colour != EDGE and inside(np.asarray(line))]
    ax.add_collection(LineCollection(edges, colors="#555555", linewidths=1.0, zorder=1))
    ax.add_collection(LineCollection(dividers, colors="white", linewidths=1.0, linestyles=(0, (4, 4)), zorder=1))


@dataclass(frozen=True)
class _TrajectoryFigure:
    """What one scenario's trajectory figure needs, as plain data (it may be drawn in another
    process): the agents' episode-0 log files, in legend order, with their names and colours."""

    plots: Path
    suite: str
    scenario: str
    spec: Any
    logs: tuple[tuple[str, str], ...]  # (agent, log file)
    labels: tuple[tuple[str, str], ...]  # (agent, legend name)
    colours: tuple[tuple[str, str], ...]

    @property
    def key(self) -> str:
        return self.scenario


def _trajectory_figures(plots: Path, suite: Suite, agents: list[str], results: list[dict]) -> list[_TrajectoryFigure]:
    """Per scenario: the road around the episode, each agent's path in episode 0 (start o, end x),
    and from the first agent's log the lead's path and the other road users' (as jobs for
    :class:`_Drawing`)."""
    figures = []
    for entry in suite.scenarios:
        mine = [r for r in results if r.get("scenario") == entry.name and r.get("episode") == 0]
        figure = _trajectory_figure_job(plots, suite.name, entry, agents, mine)
        if figure is not None:
            figures.append(figure)
    return figures


def _trajectory_figure_job(plots: Path, suite_name: str, entry, agents: list[str], first: list[dict]):
    """Scenario ``entry``'s trajectory figure from ``first``, the results of its episode 0 (each
    shown agent's first one with a log, in the order of ``agents``); None without any."""
    colours = _colours(agents)
    logs = []
    for agent in agents:
        found = next((r for r in first if r["agent"] == agent and r.get("log")), None)
        if found is not None:
            logs.append((agent, str(found["log"])))
    if not logs:
        return None
    return _TrajectoryFigure(plots, suite_name, entry.name, entry.spec, tuple(logs),
                             tuple((a, _label(a)) for a, _ in logs), tuple((a, colours[a]) for a, _ in logs))  # fmt: skip


class FigureHelpers:
    """Helper processes for a report's trajectory figures, started ahead of it: a helper first
    imports matplotlib (and, in a fresh interpreter, the map code: a second or two), which a caller
    can overlap with running the episodes (``train benchmark`` starts them beside its workers),
    then waits for :func:`write_report` to give it figures. Children of the fork server where this
    process started one (:func:`~smarts.worker_processes.start_worker_server`: the maps are
    imported there already), else fresh interpreters (``python -c``); never a fork or a re-run of
    the caller's script. :meth:`for_figures`: none on one core or for a few figures, else one per
    core, at most three, when they come from the fork server (the caller then draws none: its
    share would first cost it the imports a helper has), one per spare core when they are fresh
    interpreters. Unused helpers end when told (:meth:`close`) or when this process ends."""

    def __init__(self, count: int, caller_draws: bool = True):
        self.processes = [_Helper() for _ in range(max(count, 0))]
        self.caller_draws = caller_draws or not self.processes
        """Whether the caller draws its share too (else only what a failed helper left)."""

    @classmethod
    def for_figures(cls, figures: int) -> FigureHelpers:
        import os

        from smarts.worker_processes import worker_server_started

        cores = os.cpu_count() or 1
        if cores < 2 or figures < 3:
            return cls(0)
        if worker_server_started():
            return cls(min(cores, 3, figures // 3), caller_draws=False)
        return cls(min(cores - 1, 3, figures // 3))

    def close(self) -> None:
        _stop(self.processes)
        self.processes = []


class _Helper:
    """One figure helper (:func:`_helper_loop`) and the line-by-line channel to it: a pipe to a child
    of the fork server, or the stdin and stdout of a fresh interpreter."""

    def __init__(self):
        from smarts.worker_processes import sigint_deferred, worker_context, worker_server_started

        self.process: Any = None
        self.channel: Any = None
        if worker_server_started():
            context = worker_context()
            self.channel, theirs = context.Pipe()
            with sigint_deferred():  # born with Ctrl-C blocked, as the workers: this process stops it
                self.process = context.Process(target=_helper_in_fork, args=(theirs,), daemon=True)
                self.process.start()
            theirs.close()
            return
        import os
        import subprocess
        import sys

        import smarts

        env = dict(os.environ)  # the helper imports this process's smarts, wherever it came from
        root = str(Path(smarts.__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
        self.process = subprocess.Popen(
            [sys.executable, "-c", "from smarts.benchmark.report import _helper_main; _helper_main()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
        )  # fmt: skip

    def tell(self, line: str) -> None:
        """Send one line (a figures folder, a pickle of more figures); a helper that died is left
        to :meth:`finish` to report."""
        with contextlib.suppress(OSError, ValueError):
            if self.channel is not None:
                self.channel.send(line)
            else:
                self.process.stdin.write(f"{line}\n".encode())
                self.process.stdin.flush()

    def finish(self) -> tuple[dict[int, Path | None], str | None]:
        """Tell it there is nothing more, wait for it: (figure index -> file it drew or None when
        there was nothing to draw, why it failed or None)."""
        if self.channel is None:
            out, err, code = (*self.process.communicate(), self.process.returncode)
            if code == 0:
                return _paths(json.loads(out or "{}")), None
            why = err.decode(errors="replace").strip().splitlines()[-1:] or [f"exit status {code}"]
            return {}, why[0]
        try:
            self.channel.send(None)
            drawn, why = self.channel.recv()
        except (EOFError, OSError) as err:
            drawn, why = {}, f"it ended early ({type(err).__name__})"
        finally:
            self.channel.close()
            self.process.join()
        if why is None and self.process.exitcode != 0:
            why = f"exit status {self.process.exitcode}"
        return (_paths(drawn), why) if why is None else ({}, why)

    def kill(self) -> None:
        self.process.kill()
        if self.channel is None:
            self.process.communicate()
        else:
            self.channel.close()
            self.process.join()


class _Drawing:
    """A report's figures drawn by helper processes (:class:`FigureHelpers`) while the caller goes
    on, the caller joining in at :meth:`result`: each figure costs a few tenths of a second of text
    layout and PNG encoding, and a report has one per scenario and one per metric. The trajectory
    figures are known first (from the logs alone); the metric figures follow once the scores are
    (:meth:`add`). A figure is drawn by whoever claims it first (:func:`_claim`), the helpers from
    the front of the list and the caller from the back, so the work divides itself however long
    the caller's own part took; what a helper claimed but did not draw (it failed) the caller
    draws. ``helpers``: started ones (used up here), how many to start, or None: as many as suit."""

    def __init__(self, figures: list, helpers: FigureHelpers | int | None = None):
        import pickle
        import tempfile

        self.figures = list(figures)
        if not isinstance(helpers, FigureHelpers):
            helpers = FigureHelpers.for_figures(len(figures)) if helpers is None else FigureHelpers(helpers)
        self.folder = Path(tempfile.mkdtemp(prefix="smarts-figures-"))
        (self.folder / "figures.pickle").write_bytes(pickle.dumps(self.figures))
        self.helpers, helpers.processes = helpers.processes, []
        self.caller_draws = helpers.caller_draws or not self.helpers
        self.redraw: list = []
        """Figures to draw again here after the others (one handed out early that differs from
        the report's own: the report's wins)."""
        self._tell(f"{self.folder}")

    def _tell(self, line: str) -> None:
        for helper in self.helpers:
            helper.tell(line)

    def add(self, figures: list) -> None:
        """More figures for the helpers (they take them up after the first ones)."""
        import pickle

        if not figures:
            return
        name = f"more{len(self.figures)}.pickle"
        (self.folder / name).write_bytes(pickle.dumps((len(self.figures), figures)))
        self.figures += figures
        self._tell(name)

    def cancel(self) -> None:
        """Stop the helpers and remove the scratch folder (the report failed before its figures)."""
        import shutil

        _stop(self.helpers)
        shutil.rmtree(self.folder, ignore_errors=True)

    def result(self) -> dict:
        """Every figure drawn: its ``key`` (a trajectory figure's scenario, ``("metric", name)``)
        -> file, in the order given; figures with nothing to draw are left out."""
        import shutil

        try:
            drawn = {}
            for k in reversed(range(len(self.figures)) if self.caller_draws else []):
                if _claim(self.folder, k):
                    drawn[k] = _draw(self.figures[k])
        finally:  # the helpers are waited for (and the scratch folder removed) whatever happens here
            finished = [helper.finish() for helper in self.helpers]
            shutil.rmtree(self.folder, ignore_errors=True)
        failed = False
        for theirs, why in finished:
            drawn.update(theirs)
            if why is not None:
                failed = True
                _log.warning("a figure helper failed (%s); drawing its figures here", why)
        if failed or not self.caller_draws:  # what a failed helper left (claimed, not drawn)
            for k, figure in enumerate(self.figures):
                if k not in drawn:
                    drawn[k] = _draw(figure)
        out = {f.key: drawn[k] for k, f in enumerate(self.figures) if drawn.get(k) is not None}
        for figure in self.redraw:
            out.pop(figure.key, None)
            if (path := _draw(figure)) is not None:
                out[figure.key] = path
        return out


def _draw(figure) -> Path | None:
    """Draw one figure job (trajectory or metric); its file, or None with nothing to draw."""
    return _metric_figure(figure) if isinstance(figure, _MetricFigure) else _trajectory_figure(figure)


def _stop(helpers: list[_Helper]) -> None:
    for helper in helpers:
        helper.kill()


def _claim(folder: Path, k: int) -> bool:
    """Whether this process is the first to claim figure ``k`` (a file created exclusively)."""
    import os

    try:
        os.close(os.open(folder / f"{k}.claim", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def _paths(drawn: dict) -> dict[int, Path | None]:
    return {int(k): None if path is None else Path(path) for k, path in drawn.items()}


def _helper_main() -> None:
    """A figure helper in a fresh interpreter: lines on stdin, index -> file as JSON on stdout."""
    import sys

    lines = (line.strip() for line in sys.stdin)
    sys.stdout.write(json.dumps({k: path and str(path) for k, path in _helper_loop(lines).items()}))


def _helper_in_fork(channel) -> None:
    """A figure helper forked from the fork server: lines through ``channel`` (None ends them),
    then (index -> file, None) back, or ({}, why it failed)."""
    try:
        drawn, why = _helper_loop(iter(channel.recv, None)), None
    except Exception as err:  # noqa: BLE001 - the parent draws them itself and says why
        drawn, why = {}, f"{type(err).__name__}: {err}"
    channel.send(({k: path and str(path) for k, path in drawn.items()}, why))


def _helper_loop(lines) -> dict[int, Path | None]:
    """What a figure helper does: imports what drawing takes, then reads the folder of its
    parent's pickled figures from ``lines`` (nothing: it is not needed after all) and draws those
    it claims first; each further line names a pickle of more figures (their first index, the
    figures), until the lines end. It runs at a low priority (:data:`BACKGROUND_NICE`): while
    episodes run it takes only the CPU they leave."""
    import pickle

    _lower_priority()
    prepare_drawing()  # (nothing left to import in a child of a fork server that imported it)
    line = next(lines, "")
    if not line:
        return {}
    folder = Path(line)
    drawn: dict[int, Path | None] = {}

    def draw(first: int, figures: list) -> None:
        for k, figure in enumerate(figures, start=first):
            if _claim(folder, k):
                drawn[k] = _draw(figure)  # None: nothing to draw

    draw(0, pickle.loads((folder / "figures.pickle").read_bytes()))
    for line in lines:
        if line:
            draw(*pickle.loads((folder / line).read_bytes()))
    return drawn


def _trajectory_figure(figure: _TrajectoryFigure) -> Path | None:
    """One scenario's trajectory figure (see :func:`_trajectory_figures`); None without agent paths."""
    plt = _pyplot()
    from smarts.env.assembly import scenario_map

    logs = {}
    for agent, file in figure.logs:
        log = read_episode(file)
        if log.agents:
            logs[agent] = log
    if not logs:
        return None
    colours, names = dict(figure.colours), dict(figure.labels)
    scene_log = next((log for log in logs.values() if log.scene is not None), None)
    tracks, lead_tracks = {}, {}
    if scene_log is not None:
        scene = scene_log.scene
        tracks = _tracks(scene)
        lead_ids = {scene.ids.index(v) for v in scene.leads.values() if v in scene.ids}
        lead_tracks = {i: tracks.pop(i) for i in sorted(lead_ids) if i in tracks}
    focus = [np.stack([t.x, t.y], axis=1) for log in logs.values() for t in log.agents.values() if t.num_steps]
    focus += list(lead_tracks.values())
    box, to_scale = _crop(np.concatenate(focus))
    span_x, span_y = box[1] - box[0], box[3] - box[2]
    height = float(np.clip(8.0 * span_y / span_x, 3.2, 8.0)) if to_scale else 3.4
    width = 8.0 if to_scale or span_x >= span_y else 4.5
    fig, ax = plt.subplots(figsize=(width, height if span_x >= span_y or to_scale else 8.0))
    ax.set_facecolor("#f3f6f0")
    _draw_road(ax, scenario_map(figure.spec), box)
    if tracks:  # one artist for all of them (a busy scene has dozens)
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(list(tracks.values()), colors=TRAFFIC_COLOUR, linewidths=1.0, alpha=0.8,
                                         zorder=2, label=f"other road users ({len(tracks)}; square: last seen)"))  # fmt: skip
        last = np.array([xy[-1] for xy in tracks.values()])
        ax.plot(last[:, 0], last[:, 1], "s", color=TRAFFIC_COLOUR, markersize=3, zorder=2)
    for k, xy in enumerate(lead_tracks.values()):
        # Above the agents (who drive where it drove), dashed so their colours show between.
        ax.plot(xy[:, 0], xy[:, 1], color="black", linewidth=1.6, linestyle=(0, (5, 3)), zorder=6,
                label="lead vehicle" if k == 0 else None)  # fmt: skip
        ax.plot(xy[:1, 0], xy[:1, 1], "o", color="black", markersize=5, zorder=6)
        ax.plot(xy[-1:, 0], xy[-1:, 1], "x", color="black", markersize=6, mew=1.5, zorder=6)
    for agent, log in logs.items():
        several = len(log.agents) > 1
        for j, (agent_id, t) in enumerate(log.agents.items()):
            if not t.num_steps:
                continue
            style = ("-", "--", ":", "-.")[j % 4]
            name = names[agent] + (f" · {agent_id}" if several else "")
            ax.plot(t.x, t.y, color=colours[agent], linewidth=2.0, linestyle=style, zorder=4, label=name)
            ax.plot(t.x[:1], t.y[:1], "o", color=colours[agent], markersize=5, zorder=5)
            ax.plot(t.x[-1:], t.y[-1:], "x", color=colours[agent], markersize=7, mew=2, zorder=5)
    ax.plot([], [], "ko", markersize=4, label="start")
    ax.plot([], [], "kx", markersize=6, mew=2, label="end of the path")
    ax.set_xlim(box[0], box[1])
    ax.set_ylim(box[2], box[3])
    if to_scale:
        ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    seed = next(iter(logs.values())).seed
    scale = "" if to_scale else f"; not to scale: {'y' if span_x >= span_y else 'x'} stretched to show the lanes"
    ax.set_title(f"{figure.suite} · {figure.scenario}: episode 0 (seed {seed}{scale})", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    path = _save(fig, figure.plots / f"trajectories_{figure.scenario}.png")
    plt.close(fig)
    return path


def _tensorboard(folder: Path, suite: Suite, scores: dict, names: tuple[str, ...], label) -> None:
    """Each agent's overall metrics (step 0) and per-scenario S_bench (step = scenario index) as
    TensorBoard scalars, one run folder per agent. Written with the ``tensorboard`` package's own
    event writer (the one torch's ``SummaryWriter`` wraps): the report's process need not import
    torch, 1.5 s, for a few numbers."""
    import time

    from tensorboard.compat.proto.event_pb2 import Event
    from tensorboard.compat.proto.summary_pb2 import Summary
    from tensorboard.summary.writer.event_file_writer import EventFileWriter

    def scalar(tag: str, value: float, step: int) -> Event:
        summary = Summary(value=[Summary.Value(tag=tag, simple_value=float(value))])
        return Event(wall_time=time.time(), step=step, summary=summary)

    for agent, s in scores.items():
        if s is None:
            continue
        writer = EventFileWriter(str(folder / label(agent)))
        try:
            for name in names:
                writer.add_event(scalar(f"{suite.name}/{name}", s.overall[name], 0))
            for k, entry in enumerate(suite.scenarios):
                row = s.scenarios.get(entry.name)
                if row is not None:
                    writer.add_event(scalar(f"{suite.name}/scenario_S_bench", row["S_bench"], k))
        finally:
            writer.close()
