"""Every constant of the benchmark metrics, as a validated dataclass loaded from YAML.

The defaults are the paper's; ``configs/benchmark/metrics.yaml`` (installed with the package as
``smarts.configs``) repeats them so a reader sees the numbers a score was computed with, and a run
can override them with its own file. A YAML file may give any subset of the keys; the rest keep
their defaults. Unknown keys are errors, so a typo never silently leaves a default in place.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import Field, model_validator

from smarts.core.errors import MetricParamsError
from smarts.core.resources import config_path
from smarts.core.schema import Schema, load_yaml, validate

DEFAULT_CONFIG_PATH = config_path("benchmark", "metrics.yaml")
"""The shipped metrics config (``configs/benchmark/metrics.yaml``); used by :func:`load_params`."""

FAILED_EPISODE_POLICIES = ("worst", "exclude")


Weight = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]


class Weights(Schema):
    """S_bench weights; only the task's own metric (MTE or SFD) enters a suite's score."""

    pr: Weight = 0.1
    rc: Weight = 0.45
    humanness: Weight = 0.15
    mte: Weight = Field(0.3, description="Used for the collaborative task.")
    sfd: Weight = Field(0.3, description="Used for the adaptive task.")

    @model_validator(mode="after")
    def _some_weight(self) -> Weights:
        base = self.pr + self.rc + self.humanness
        if base + self.mte <= 0 or base + self.sfd <= 0:
            raise ValueError("the weights of a task must not all be zero")
        return self


class HumannessParams(Schema):
    """Comfort thresholds (a step is uncomfortable when any ratio exceeds 1) and lane centring."""

    penalty_period_s: Weight = Field(
        3.0, description="T_p: an uncomfortable step keeps the comfort cost on for this long afterwards (s)."
    )
    jerk_long_max: Positive = Field(0.9, description="m/s^3.")
    jerk_lat_max: Positive = Field(0.9, description="m/s^3.")
    accel_long_max: Positive = Field(2.0, description="m/s^2.")
    accel_lat_max: Positive = Field(1.47, description="m/s^2.")
    lane_offset_scale: Positive = Field(
        0.5, description="The lane-centre cost saturates at 1 when |offset| reaches this fraction of the lane width."
    )


class RuleWeights(Schema):
    """Weights of RC's terms: RC = 1 - the weighted mean of the terms that apply. The paper's three
    terms weigh the same; the red-light term applies only on maps with traffic signals, so suites
    without signals score exactly as the paper's RC."""

    overspeed: Weight = 1.0
    wrong_way: Weight = 1.0
    off_road: Weight = 1.0
    red_light: Weight = Field(1.0, description="Entering a junction lane on red (maps with signals only).")

    @model_validator(mode="after")
    def _some_weight(self) -> RuleWeights:
        if self.overspeed + self.wrong_way + self.off_road <= 0:
            raise ValueError("overspeed, wrong_way and off_road must not all weigh zero (RC needs a term everywhere)")
        return self


class RulesParams(Schema):
    """Road-rule compliance."""

    overspeed_scale: Positive = Field(
        0.5, description="The speeding cost saturates at 1 when the excess reaches this fraction of the limit."
    )
    weights: RuleWeights = RuleWeights()


class FollowingParams(Schema):
    """Vehicle following (adaptive task): the follow margin and the time-gap cap.

    Follow margin FM = standstill_distance_m + safe_headway_s * ego speed, the free space the
    ego should keep to its lead. The time gap to FM is (gap - FM) / ego speed; gaps beyond
    ``max_time_gap_s`` count as fully lost contact.
    """

    max_time_gap_s: Positive = 3.0
    safe_headway_s: Positive = 1.0
    standstill_distance_m: Positive = 2.5


class MetricParams(Schema):
    """All metric constants; ``MetricParams()`` is the paper's defaults."""

    weights: Weights = Weights()
    humanness: HumannessParams = HumannessParams()
    rules: RulesParams = RulesParams()
    following: FollowingParams = FollowingParams()
    failed_episodes: Literal["worst", "exclude"] = Field(
        "worst",
        description=(
            "worst: a failed episode scores 0 on every metric (its costs are 1) and still counts in "
            "its scenario's mean, so failing is never better than driving badly. exclude: failed "
            "episodes are left out of the means and only listed in the report."
        ),
    )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, source: str = "<dict>") -> MetricParams:
        """Build from a (possibly partial) nested mapping; unknown keys and bad values raise."""
        return validate(cls, data, source, MetricParamsError)

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump()


def load_params(path: str | os.PathLike | None = None) -> MetricParams:
    """Load metric constants from ``path``; with None, from the shipped config.

    Should that file be missing, the defaults are used: they equal its contents (a test keeps the
    two in step).
    """
    if path is None:
        if not DEFAULT_CONFIG_PATH.is_file():
            return MetricParams()
        path = DEFAULT_CONFIG_PATH
    data = load_yaml(path, "metrics config", MetricParamsError)
    return MetricParams.from_dict(data, source=str(path))
