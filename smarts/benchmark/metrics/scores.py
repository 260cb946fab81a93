"""The benchmark metrics (PR, RC, Humanness, MTE, SFD, S_bench) computed from episode logs.

Every metric is ``1 - cost`` with a cost in [0, 1] per mission vehicle; higher is better.
Averaging order: per vehicle over its steps, then over the vehicles of an episode, then over the
episodes of a scenario, then over scenarios (each scenario weighs the same however many
episodes it ran). Because every metric is linear in its cost, ``1 - mean(cost)`` equals
``mean(1 - cost)`` at every level.

Per-vehicle costs (``p`` = :class:`MetricParams`):

- progress (PR): ``min(d_final, d_init) / d_init``, ``d`` the route distance to the goal.
  ``d_init`` is the metadata's initial route distance (measured at the mission start, before the
  first logged step); ``d_final`` is the last row's ``route_distance_to_goal``, or 0 once
  ``goal_reached`` was set (arriving within the goal radius completes the route; the residual
  inside the radius is not a shortfall). A zero-length route (``d_init == 0``) costs 0: the
  vehicle is already there.
- humanness: ``(comfort + mean_steps(lane_centre)) / 2``.
  ``dyn_t = max(|jerk_long|/jl, |jerk_lat|/jt, |accel_long|/al, |accel_lat|/at)``; with
  ``T_trv`` the vehicle's logged steps and ``T_p = round(penalty_period_s / dt)`` steps,
  ``u_t = 1`` for ``t = 1..T_trv+T_p`` when ``max(dyn_t' for t' in [max(1, t-T_p), min(T_trv, t)]) > 1``,
  so one uncomfortable step at ``k`` switches ``u`` on for steps ``k..k+T_p`` (``T_p + 1`` steps);
  ``comfort = sum(u) / (T_trv + T_p)``. ``lane_centre = 1`` on rows fully off road, else
  ``min(|lane_offset| / (lane_offset_scale * lane_width), 1)``.
- rules (RC): the weighted mean (``p.rules.weights``, 1 each by default) of
  ``overspeed = mean_steps(min(max(v - v_limit, 0) / (overspeed_scale * v_limit), 1))``,
  ``wrong_way_ever``, ``off_road_ever`` and, on maps with traffic signals only (the log's
  ``signals`` > 0), ``red_light_ever``: with the default weights ``(overspeed + wrong_way +
  off_road) / 3`` as in the paper where there are no signals, ``(... + red_light) / 4`` where
  there are. ``off_road_ever`` is set when any row has ``partial_off_road`` or ``off_road``,
  except a row marked ``left_map``; ``red_light_ever`` when any row has ``red_light`` (the
  vehicle entered a junction lane whose signal was red at that moment; yellow is no violation).

  The end of the map is not the edge of the road. A vehicle that drives past the end of the last
  lane of its route, where the map stops (a lane without successors), has left the map, as SUMO
  removes a vehicle at its route's end: the recorder ends its trace on its last row inside the
  map and marks that row ``left_map``, and any ``partial_off_road``/``off_road`` on a
  ``left_map`` row is no violation. Leaving the road sideways, or off the end of a lane that is
  not on the route, is still off road.
- time (MTE, collaborative): ``T_arrive / T_limit``, ``T_arrive`` the ``time`` of the first row
  with ``goal_reached`` (clipped to ``T_limit``), ``T_limit`` when the goal is never reached.
- follow gap (SFD, adaptive): mean over steps of ``gap``; ``gap = 1`` when the lead is out of the
  ego's lane or out of sight, when the ego is inside the follow margin, or when the time gap to
  the margin exceeds ``max_time_gap_s``; else ``time_gap / max_time_gap_s``. "In the ego's lane"
  is lane continuity (the lead ahead on the ego's lane or on a successor lane reached from it,
  across segment boundaries; see ``smarts.benchmark.metrics.log``), not equal lane ids. A vehicle
  whose rows stop before the scenario's ``end_time`` (it crashed or left the road) keeps counting
  ``gap = 1`` for every missing step: losing the lead by crashing into it is not good following.

Rows never run past the time limit (the log validator rejects them), so PR and MTE agree on what
arrived: an agent still driving at the limit has not arrived for either.

``S_bench = (w_pr PR + w_rc RC + w_h Humanness + w_task M_task) / (w_pr + w_rc + w_h + w_task)``
with ``M_task`` = MTE (collaborative) or SFD (adaptive).

Uncertainty: :func:`score_suite` gives every metric (overall and per scenario) a confidence
interval from a stratified percentile bootstrap: episodes are resampled with replacement within
each scenario (``resamples`` times, 2000 by default, from a fixed ``ci_seed`` so reports repeat
exactly), each resample's overall value averages its scenario means equally like the point
estimate, and S_bench is recomputed from each resample's PR, RC, Humanness and task metric. The
interval is the central ``ci_level`` (95%) of the resampled values. A scenario with one episode
has no spread (its interval is its value); with few episodes the interval is optimistic.

Failed episodes (a log with a failure reason): under the default policy ``worst`` every cost of
the episode is 1 (every metric 0) and it counts like any other episode; under ``exclude`` it is
left out of every mean and only listed in :attr:`SuiteScores.failed`. :func:`score_episode`
always returns the worst values for a failed episode; the policy is applied by
:func:`score_suite`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from smarts.benchmark.metrics.following import (
    follow_margin,
    in_follow_margin,
    time_gap_to_margin,
)
from smarts.benchmark.metrics.log import (
    AgentTrace,
    EpisodeLog,
    LogError,
    validate_episode,
)
from smarts.benchmark.metrics.params import MetricParams, load_params

# The env logger's helpers, importable from here too (SFD is defined by them).
__all__ = [
    "COST_OF_METRIC",
    "TASK_METRIC",
    "AgentCosts",
    "SuiteScores",
    "agent_costs",
    "bootstrap_ci",
    "comfort_cost",
    "comfort_window",
    "follow_gap_cost",
    "follow_margin",
    "in_follow_margin",
    "lane_centre_cost",
    "metric_names",
    "overspeed_cost",
    "penalty_steps",
    "progress_cost",
    "s_bench",
    "score_episode",
    "score_suite",
    "time_cost",
    "time_gap_to_margin",
]

TASK_METRIC = {"collaborative": "MTE", "adaptive": "SFD"}
COST_OF_METRIC = {
    "PR": "progress",
    "RC": "rules",
    "Humanness": "humanness",
    "MTE": "time",
    "SFD": "follow_gap",
}


def metric_names(task: str) -> tuple[str, ...]:
    """Column order of a report: the three shared metrics, the task's own one, then S_bench."""
    return ("PR", "RC", "Humanness", TASK_METRIC[task], "S_bench")


# ------------------------------------------------------------------------- per-step cost terms
def progress_cost(
    route_distance_to_goal: np.ndarray,
    goal_reached: np.ndarray,
    initial_distance: float,
) -> float:
    """PR cost of one vehicle: the share of its route still ahead at the end, in [0, 1]."""
    if initial_distance <= 0.0:
        return 0.0
    if route_distance_to_goal.size == 0:
        return 1.0
    final = 0.0 if goal_reached.any() else float(route_distance_to_goal[-1])
    return min(final, initial_distance) / initial_distance


def comfort_window(uncomfortable: np.ndarray, penalty_steps: int) -> np.ndarray:
    """``u_t`` for ``t = 1..T_trv+T_p``: 1 where an uncomfortable step lies in ``[t-T_p, t]``."""
    n = uncomfortable.shape[0]
    counts = np.concatenate(([0], np.cumsum(uncomfortable, dtype=np.int64)))
    t = np.arange(1, n + penalty_steps + 1)
    first = np.maximum(1, t - penalty_steps)
    last = np.minimum(n, t)
    return counts[last] - counts[first - 1] > 0


def comfort_cost(trace: AgentTrace, penalty_steps: int, params: MetricParams) -> float:
    """``T_u / (T_trv + T_p)``: the share of the padded episode spent in or after discomfort."""
    h = params.humanness
    dyn = np.maximum.reduce(
        [
            np.abs(trace.jerk_long) / h.jerk_long_max,
            np.abs(trace.jerk_lat) / h.jerk_lat_max,
            np.abs(trace.accel_long) / h.accel_long_max,
            np.abs(trace.accel_lat) / h.accel_lat_max,
        ]
    )
    total = trace.num_steps + penalty_steps
    if total == 0:
        return 0.0
    return float(comfort_window(dyn > 1.0, penalty_steps).sum()) / total


def lane_centre_cost(lane_offset: np.ndarray, lane_width: np.ndarray, off_road: np.ndarray, scale: float) -> np.ndarray:
    """Per-step lane-centre cost: 1 off road, else offset over ``scale`` lane widths, capped at 1."""
    with np.errstate(invalid="ignore"):
        ratio = np.minimum(np.abs(lane_offset) / (scale * lane_width), 1.0)
    return np.where(off_road, 1.0, ratio)


def overspeed_cost(speed: np.ndarray, speed_limit: np.ndarray, scale: float) -> np.ndarray:
    """Per-step speeding cost: excess over the limit in units of ``scale * limit``, capped at 1."""
    return np.minimum(np.maximum(speed - speed_limit, 0.0) / (scale * speed_limit), 1.0)


def time_cost(time: np.ndarray, goal_reached: np.ndarray, time_limit: float) -> float:
    """MTE cost: arrival time over the time limit; 1 when the goal is never reached."""
    hits = np.flatnonzero(goal_reached)
    if hits.size == 0:
        return 1.0
    return min(max(float(time[hits[0]]), 0.0), time_limit) / time_limit


def missing_steps(trace: AgentTrace, log: EpisodeLog) -> int:
    """Steps between a vehicle's last row and the scenario's end (``log.end_time``): a vehicle
    that crashed or left the road did not complete the scenario."""
    if log.end_time is None or trace.num_steps == 0:
        return 0
    return max(int(round((float(log.end_time) - float(trace.time[-1])) / float(log.dt))), 0)


def follow_gap_cost(
    follow_time_gap: np.ndarray,
    in_follow_margin: np.ndarray,
    lead_in_lane_and_visible: np.ndarray,
    max_time_gap: float,
) -> np.ndarray:
    """Per-step SFD gap: the time gap to the follow margin in units of ``max_time_gap``, else 1."""
    usable = lead_in_lane_and_visible & ~in_follow_margin
    with np.errstate(invalid="ignore"):
        within = usable & (follow_time_gap <= max_time_gap)
        return np.where(within, follow_time_gap / max_time_gap, 1.0)


# ------------------------------------------------------------------------ per-vehicle costs
@dataclass(frozen=True)
class AgentCosts:
    """The inner cost terms of one mission vehicle in one episode, each in [0, 1]."""

    progress: float
    comfort: float
    lane_centre: float
    overspeed: float
    wrong_way: float
    off_road: float
    time: float | None = None
    """MTE cost; collaborative task only."""
    follow_gap: float | None = None
    """SFD cost; adaptive task only."""
    red_light: float | None = None
    """Red-light cost; None where the map has no signals (the rule cannot apply)."""
    rule_weights: tuple[float, float, float, float] = field(default=(1.0, 1.0, 1.0, 1.0), repr=False)
    """Weights of overspeed, wrong_way, off_road and red_light in ``rules`` (``p.rules.weights``)."""

    @property
    def humanness(self) -> float:
        return (self.comfort + self.lane_centre) / 2.0

    @property
    def rules(self) -> float:
        """The weighted mean of the RC terms that apply (red_light only where there are signals)."""
        w_speed, w_way, w_off, w_red = self.rule_weights
        terms = [(w_speed, self.overspeed), (w_way, self.wrong_way), (w_off, self.off_road)]
        if self.red_light is not None:
            terms.append((w_red, self.red_light))
        total = sum(w for w, _ in terms)
        return sum(w * c for w, c in terms) / total

    def as_dict(self) -> dict[str, float]:
        out = {k: v for k, v in asdict(self).items() if v is not None and k != "rule_weights"}
        out.update(humanness=self.humanness, rules=self.rules)
        return out

    @classmethod
    def worst(cls, task: str, signals: bool = False) -> AgentCosts:
        return cls(
            progress=1.0,
            comfort=1.0,
            lane_centre=1.0,
            overspeed=1.0,
            wrong_way=1.0,
            off_road=1.0,
            time=1.0 if task == "collaborative" else None,
            follow_gap=1.0 if task == "adaptive" else None,
            red_light=1.0 if signals else None,
        )


def penalty_steps(dt: float, params: MetricParams) -> int:
    """T_p in steps: ``round(penalty_period_s / dt)``."""
    return round(params.humanness.penalty_period_s / dt)


def agent_costs(log: EpisodeLog, params: MetricParams | None = None) -> dict[str, AgentCosts]:
    """Every mission vehicle's cost terms; a failed episode gives the worst costs to each agent."""
    params = load_params() if params is None else params
    validate_episode(log)
    if log.failed:
        return {a: AgentCosts.worst(log.task, log.signals > 0) for a in log.agents}
    rw = params.rules.weights
    weights = (rw.overspeed, rw.wrong_way, rw.off_road, rw.red_light)
    steps_p = penalty_steps(log.dt, params)
    out: dict[str, AgentCosts] = {}
    for agent_id, tr in log.agents.items():
        follow = None
        if log.task == "adaptive":
            gaps = follow_gap_cost(
                tr.follow_time_gap,
                tr.in_follow_margin,
                tr.lead_in_lane_and_visible,
                params.following.max_time_gap_s,
            )
            missed = missing_steps(tr, log)  # the vehicle left before the scenario ended
            follow = float((gaps.sum() + missed) / (gaps.size + missed))
        out[agent_id] = AgentCosts(
            progress=progress_cost(
                tr.route_distance_to_goal,
                tr.goal_reached,
                float(log.initial_route_distance[agent_id]),
            ),
            comfort=comfort_cost(tr, steps_p, params),
            lane_centre=float(
                lane_centre_cost(
                    tr.lane_offset,
                    tr.lane_width,
                    tr.off_road,
                    params.humanness.lane_offset_scale,
                ).mean()
            ),
            overspeed=float(overspeed_cost(tr.speed, tr.speed_limit, params.rules.overspeed_scale).mean()),
            wrong_way=float(tr.wrong_way.any()),
            # leaving the map at its route's end is not leaving the road
            off_road=float(((tr.partial_off_road | tr.off_road) & ~tr.flag("left_map")).any()),
            red_light=float(tr.flag("red_light").any()) if log.signals > 0 else None,
            rule_weights=weights,
            time=time_cost(tr.time, tr.goal_reached, float(log.time_limit)) if log.task == "collaborative" else None,
            follow_gap=follow,
        )
    return out


# ------------------------------------------------------------------------------ per episode
def s_bench(metrics: dict[str, float], task: str, params: MetricParams) -> float:
    """Weighted mean of PR, RC, Humanness and the task's metric."""
    w = params.weights
    task_metric = TASK_METRIC[task]
    pairs = [
        (w.pr, metrics["PR"]),
        (w.rc, metrics["RC"]),
        (w.humanness, metrics["Humanness"]),
        (w.mte if task_metric == "MTE" else w.sfd, metrics[task_metric]),
    ]
    return sum(wi * m for wi, m in pairs) / sum(wi for wi, _ in pairs)


def score_episode(log: EpisodeLog, params: MetricParams | None = None) -> dict[str, float]:
    """One episode's metrics and mean inner costs.

    Keys: ``PR``, ``RC``, ``Humanness``, ``MTE`` or ``SFD``, ``S_bench`` (each in [0, 1], higher
    is better) and ``cost.<term>`` for every inner term averaged over the episode's vehicles
    (``progress``, ``comfort``, ``lane_centre``, ``humanness``, ``overspeed``, ``wrong_way``,
    ``off_road``, ``rules``, ``time`` or ``follow_gap``). A failed episode scores 0 on every
    metric (every cost 1).
    """
    params = load_params() if params is None else params
    per_agent = agent_costs(log, params)
    if per_agent:
        rows = [c.as_dict() for c in per_agent.values()]
        costs = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    else:  # a failed episode that never spawned its agents
        costs = AgentCosts.worst(log.task, log.signals > 0).as_dict()
    metrics = {m: 1.0 - costs[COST_OF_METRIC[m]] for m in metric_names(log.task)[:-1]}
    metrics["S_bench"] = s_bench(metrics, log.task, params)
    metrics.update({f"cost.{k}": v for k, v in costs.items()})
    return metrics


# ---------------------------------------------------------------------------------- per suite
CI_LEVEL = 0.95
CI_RESAMPLES = 2000
CI_SEED = 0


def ci_method(level: float = CI_LEVEL, resamples: int = CI_RESAMPLES, seed: int = CI_SEED) -> str:
    """The sentence a report prints under its tables to say how its intervals were made."""
    return (
        f"{level:.0%} confidence intervals: stratified percentile bootstrap over episodes "
        f"({resamples} resamples, seed {seed}): episodes are resampled with replacement within each "
        "scenario, scenarios are averaged equally as in the point estimate, and S_bench is recomputed "
        "per resample. A scenario with one episode has no spread; with few episodes the intervals "
        "are optimistic."
    )


def _weights(task: str, params: MetricParams) -> np.ndarray:
    w = params.weights
    return np.array([w.pr, w.rc, w.humanness, w.mte if TASK_METRIC[task] == "MTE" else w.sfd])


def bootstrap_ci(
    per_scenario: dict[str, Sequence[dict[str, float]]],
    task: str,
    params: MetricParams,
    level: float = CI_LEVEL,
    resamples: int = CI_RESAMPLES,
    seed: int = CI_SEED,
) -> tuple[dict[str, tuple[float, float]], dict[str, dict[str, tuple[float, float]]]]:
    """``(overall, per scenario)`` intervals ``(low, high)`` for every metric of ``task``.

    ``per_scenario`` maps a scenario to its scored episodes (:func:`score_episode` dicts).
    Stratified bootstrap: within each scenario (in sorted order, from one generator seeded with
    ``seed``) its ``n`` episodes are resampled ``n`` at a time with replacement, ``resamples``
    times; the overall value of a resample is the equal-weight mean of its scenario means, and
    S_bench is computed from the resampled PR, RC, Humanness and task metric.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"ci level must be in (0, 1), got {level!r}")
    if resamples < 1:
        raise ValueError(f"resamples must be >= 1, got {resamples!r}")
    names = metric_names(task)
    base = names[:-1]
    w = _weights(task, params)
    rng = np.random.default_rng(seed)
    q = [(1.0 - level) / 2.0, 1.0 - (1.0 - level) / 2.0]
    means = {}
    scenario_ci: dict[str, dict[str, tuple[float, float]]] = {}

    def interval(values: np.ndarray, point: float) -> tuple[float, float]:
        lo, hi = np.quantile(values, q)
        # Rounding noise aside, a percentile interval of a mean contains the mean.
        return (float(min(lo, point)), float(max(hi, point)))

    for name in sorted(per_scenario):
        rows = per_scenario[name]
        m = np.array([[r[k] for k in base] for r in rows], dtype=np.float64)  # [n, 4]
        idx = rng.integers(0, len(m), size=(resamples, len(m)))
        sample = m[idx].mean(axis=1)  # [B, 4]
        means[name] = sample
        point = m.mean(axis=0)
        with_s = np.concatenate([sample, (sample @ w / w.sum())[:, None]], axis=1)
        point_s = np.append(point, point @ w / w.sum())
        scenario_ci[name] = {k: interval(with_s[:, i], float(point_s[i])) for i, k in enumerate(names)}
    overall = np.mean(np.stack(list(means.values())), axis=0)  # [B, 4]
    overall = np.concatenate([overall, (overall @ w / w.sum())[:, None]], axis=1)
    point_all = np.mean([[np.mean([r[k] for r in per_scenario[n]]) for k in base] for n in per_scenario], axis=0)
    point_all = np.append(point_all, point_all @ w / w.sum())
    overall_ci = {k: interval(overall[:, i], float(point_all[i])) for i, k in enumerate(names)}
    return overall_ci, scenario_ci


@dataclass
class SuiteScores:
    """A suite's scores: the overall metrics, a per-scenario table and the failed episodes, with
    confidence intervals and the episodes' seeds."""

    task: str
    overall: dict[str, float]
    """``PR``, ``RC``, ``Humanness``, ``MTE`` or ``SFD``, ``S_bench``: means over scenarios."""
    scenarios: dict[str, dict[str, float]]
    """Scenario -> mean over its scored episodes of every :func:`score_episode` key."""
    episodes: dict[str, int]
    """Scenario -> number of episodes that entered its mean."""
    failed: list[dict[str, Any]] = field(default_factory=list)
    """One entry per failed episode: scenario, episode, seed, failure, source, excluded."""
    policy: str = "worst"
    overall_ci: dict[str, tuple[float, float]] = field(default_factory=dict)
    """Metric -> (low, high) confidence interval of the overall value (see ``ci``)."""
    scenario_ci: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    """Scenario -> metric -> (low, high) confidence interval of the scenario mean."""
    seeds: dict[str, dict[int, int | None]] = field(default_factory=dict)
    """Scenario -> episode index -> seed, for every episode given (failed ones included)."""
    episode_scores: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    """Scenario -> one entry per episode (episode, seed, failed, excluded and its metrics)."""
    ci: dict[str, Any] = field(default_factory=dict)
    """How the intervals were made: level, resamples, seed and method (a sentence)."""

    @property
    def metric_names(self) -> tuple[str, ...]:
        return metric_names(self.task)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def format_table(self) -> str:
        """A plain-text table: one row per scenario, then the overall row, each metric with its
        confidence interval; then the episodes' seeds and the failed episodes."""
        names = self.metric_names
        width = max([len("overall"), *map(len, self.scenarios)])
        cell = 21

        def fmt(value: float, ci: tuple[float, float] | None) -> str:
            text = f"{value:.3f}" + (f" [{ci[0]:.3f},{ci[1]:.3f}]" if ci else "")
            return f"{text:>{cell}}"

        head = f"{'scenario':<{width}}  {'episodes':>8}  " + "  ".join(f"{n:>{cell}}" for n in names)
        lines = [f"task: {self.task}", head, "-" * len(head)]
        for scenario, row in self.scenarios.items():
            cis = self.scenario_ci.get(scenario, {})
            values = "  ".join(fmt(row[n], cis.get(n)) for n in names)
            lines.append(f"{scenario:<{width}}  {self.episodes[scenario]:>8d}  {values}")
        lines.append("-" * len(head))
        total = sum(self.episodes.values())
        lines.append(
            f"{'overall':<{width}}  {total:>8d}  "
            + "  ".join(fmt(self.overall[n], self.overall_ci.get(n)) for n in names)
        )
        if self.ci:
            lines.append(self.ci.get("method", ""))
        if self.seeds:
            lines.append("episodes (index=seed):")
            for scenario, seeds in self.seeds.items():
                lines.append(f"  {scenario}: " + ", ".join(f"{e}={s}" for e, s in seeds.items()))
        if self.failed:
            verb = "excluded" if self.policy == "exclude" else "scored as worst"
            lines.append(f"failed episodes ({verb}):")
            lines += [f"  {f['scenario']} #{f['episode']} (seed {f.get('seed')}): {f['failure']}" for f in self.failed]
        return "\n".join(lines)


def score_suite(
    logs: Sequence[EpisodeLog],
    params: MetricParams | None = None,
    *,
    ci_level: float = CI_LEVEL,
    resamples: int = CI_RESAMPLES,
    ci_seed: int = CI_SEED,
    score: Callable[[EpisodeLog, MetricParams], dict[str, float]] = score_episode,
) -> SuiteScores:
    """Score a suite: episodes are averaged per scenario first, then scenarios equally; every
    mean gets a confidence interval (:func:`bootstrap_ci`, ``ci_level``, ``resamples``,
    ``ci_seed``). ``score``: how one episode is scored, :func:`score_episode` or a caller's lookup
    of what it computed with it already (a benchmark scores each log as its episode finishes).

    All logs must share one task (S_bench's fourth metric differs between tasks: score each task
    separately). The same (scenario, episode index) twice is an error, as is a scenario whose
    episodes disagree on the task.
    """
    params = load_params() if params is None else params
    task = _suite_task(logs)
    names = metric_names(task)
    per_scenario, failed, seeds, episode_scores = _score_episodes(logs, params, names, score)
    if not per_scenario:
        raise ValueError("score_suite: every episode failed and failed episodes are excluded; nothing to score")

    scenarios: dict[str, dict[str, float]] = {}
    for name in sorted(per_scenario):
        rows = per_scenario[name]
        keys = dict.fromkeys(k for r in rows for k in r)  # cost.red_light: not in a failed episode's worst row
        scenarios[name] = {k: float(np.mean([r[k] for r in rows if k in r])) for k in keys}
    overall = {m: float(np.mean([row[m] for row in scenarios.values()])) for m in names[:-1]}
    overall["S_bench"] = s_bench(overall, task, params)
    overall_ci, scenario_ci = bootstrap_ci(per_scenario, task, params, ci_level, resamples, ci_seed)
    failed.sort(key=lambda f: (f["scenario"], f["episode"]))
    return SuiteScores(
        task=task,
        overall=overall,
        scenarios=scenarios,
        episodes={name: len(per_scenario[name]) for name in scenarios},
        failed=failed,
        policy=params.failed_episodes,
        overall_ci=overall_ci,
        scenario_ci=scenario_ci,
        seeds={name: dict(sorted(seeds[name].items())) for name in sorted(seeds)},
        episode_scores={
            name: sorted(rows, key=lambda r: r["episode"]) for name, rows in sorted(episode_scores.items())
        },
        ci={
            "level": ci_level,
            "resamples": resamples,
            "seed": ci_seed,
            "method": ci_method(ci_level, resamples, ci_seed),
        },
    )


def _suite_task(logs: Sequence[EpisodeLog]) -> str:
    """The one task all logs share (a log that fails validation is named before a mix of tasks is)."""
    if not logs:
        raise ValueError("score_suite: no episode logs given")
    tasks = sorted({log.task for log in logs})
    if len(tasks) != 1 or tasks[0] not in TASK_METRIC:
        for log in logs:
            validate_episode(log)
        raise ValueError(f"score_suite: logs mix tasks {tasks}; score each task's logs separately")
    return tasks[0]


def _score_episodes(logs: Sequence[EpisodeLog], params: MetricParams, names: tuple[str, ...], score) -> tuple:
    """Score every episode once; returns the scores kept per scenario (failed ones dropped when the
    policy excludes them), the failed episodes, the seeds and every episode's row for the report."""
    seen: dict[tuple[str, int], str | None] = {}
    per_scenario: dict[str, list[dict[str, float]]] = {}
    failed: list[dict[str, Any]] = []
    seeds: dict[str, dict[int, int | None]] = {}
    episode_scores: dict[str, list[dict[str, Any]]] = {}
    exclude = params.failed_episodes == "exclude"
    for log in logs:
        scores = score(log, params)
        key = (log.scenario, int(log.episode))
        if key in seen:
            raise LogError(
                f"episode {log.episode} of scenario {log.scenario!r} appears twice (also in {seen[key] or '<in-memory log>'})",
                source=log.source,
            )
        seen[key] = log.source
        seed = None if log.seed is None else int(log.seed)
        seeds.setdefault(log.scenario, {})[int(log.episode)] = seed
        episode_scores.setdefault(log.scenario, []).append(
            {
                "episode": int(log.episode),
                "seed": seed,
                "failed": log.failed,
                "excluded": log.failed and exclude,
                **{m: scores[m] for m in names},
            }  # fmt: skip
        )
        if log.failed:
            failed.append(
                {
                    "scenario": log.scenario,
                    "episode": int(log.episode),
                    "seed": seed,
                    "failure": log.failure,
                    "source": log.source,
                    "excluded": exclude,
                }
            )
            if exclude:
                continue
        per_scenario.setdefault(log.scenario, []).append(scores)
    return per_scenario, failed, seeds, episode_scores
