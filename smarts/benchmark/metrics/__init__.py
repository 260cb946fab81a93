"""Benchmark metrics scored from episode logs (never from a live simulator).

Write logs with :func:`write_episode`, score them with :func:`score_suite`, or from a shell:
``python -m smarts.benchmark.metrics LOGS_DIR``.
"""

from smarts.benchmark.metrics.following import (
    follow_margin,
    in_follow_margin,
    time_gap_to_margin,
)
from smarts.benchmark.metrics.log import (
    ALL_COLUMNS,
    FOLLOW_COLUMNS,
    REQUIRED_COLUMNS,
    TASKS,
    AgentTrace,
    EpisodeLog,
    episode_filename,
    export_csv,
    export_jsonl,
    read_episode,
    read_episodes,
    validate_episode,
    write_episode,
)
from smarts.benchmark.metrics.params import (
    DEFAULT_CONFIG_PATH,
    FollowingParams,
    HumannessParams,
    MetricParams,
    RulesParams,
    Weights,
    load_params,
)
from smarts.benchmark.metrics.scores import (
    TASK_METRIC,
    AgentCosts,
    SuiteScores,
    agent_costs,
    metric_names,
    score_episode,
    score_suite,
)
from smarts.core.errors import LogError, MetricParamsError

__all__ = [
    "ALL_COLUMNS",
    "DEFAULT_CONFIG_PATH",
    "FOLLOW_COLUMNS",
    "REQUIRED_COLUMNS",
    "TASKS",
    "TASK_METRIC",
    "AgentCosts",
    "AgentTrace",
    "EpisodeLog",
    "FollowingParams",
    "HumannessParams",
    "LogError",
    "MetricParams",
    "MetricParamsError",
    "RulesParams",
    "SuiteScores",
    "Weights",
    "agent_costs",
    "episode_filename",
    "export_csv",
    "export_jsonl",
    "follow_margin",
    "in_follow_margin",
    "load_params",
    "metric_names",
    "read_episode",
    "read_episodes",
    "score_episode",
    "score_suite",
    "time_gap_to_margin",
    "validate_episode",
    "write_episode",
]
