"""Every constant of the benchmark metrics, as a validated dataclass loaded from YAML.

The defaults are the paper's; ``configs/benchmark/metrics.yaml`` repeats them so a reader sees the
numbers a score was computed with, and a run can override them with its own file. A YAML file
may give any subset of the keys; the rest keep their defaults. Unknown keys are errors, so a
typo never silently leaves a default in place.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

import yaml

DEFAULT_CONFIG_PATH = (
    Path(__file__).resolve().parents[3] / "configs" / "benchmark" / "metrics.yaml"
)
"""The repository's metrics config; used by :func:`load_params` when it exists."""

FAILED_EPISODE_POLICIES = ("worst", "exclude")


class MetricParamsError(ValueError):
    """A metrics config file or value is invalid; the message names the file and key."""


@dataclass(frozen=True)
class Weights:
    """S_bench weights; only the task's own metric (MTE or SFD) enters a suite's score."""

    pr: float = 0.1
    rc: float = 0.45
    humanness: float = 0.15
    mte: float = 0.3
    """Used for the collaborative task."""
    sfd: float = 0.3
    """Used for the adaptive task."""


@dataclass(frozen=True)
class HumannessParams:
    """Comfort thresholds (a step is uncomfortable when any ratio exceeds 1) and lane centring."""

    penalty_period_s: float = 3.0
    """T_p: an uncomfortable step keeps the comfort cost on for this long afterwards (s)."""
    jerk_long_max: float = 0.9
    """m/s^3."""
    jerk_lat_max: float = 0.9
    """m/s^3."""
    accel_long_max: float = 2.0
    """m/s^2."""
    accel_lat_max: float = 1.47
    """m/s^2."""
    lane_offset_scale: float = 0.5
    """The lane-centre cost saturates at 1 when |offset| reaches this fraction of the lane width."""


@dataclass(frozen=True)
class RulesParams:
    """Road-rule compliance."""

    overspeed_scale: float = 0.5
    """The speeding cost saturates at 1 when the excess reaches this fraction of the limit."""


@dataclass(frozen=True)
class FollowingParams:
    """Vehicle following (adaptive task): the follow margin and the time-gap cap.

    Follow margin FM = standstill_distance_m + safe_headway_s * ego speed, the free space the
    ego should keep to its lead. The time gap to FM is (gap - FM) / ego speed; gaps beyond
    ``max_time_gap_s`` count as fully lost contact.
    """

    max_time_gap_s: float = 3.0
    safe_headway_s: float = 1.0
    standstill_distance_m: float = 2.5


@dataclass(frozen=True)
class MetricParams:
    """All metric constants; ``MetricParams()`` is the paper's defaults."""

    weights: Weights = field(default_factory=Weights)
    humanness: HumannessParams = field(default_factory=HumannessParams)
    rules: RulesParams = field(default_factory=RulesParams)
    following: FollowingParams = field(default_factory=FollowingParams)
    failed_episodes: str = "worst"
    """``worst``: a failed episode scores 0 on every metric (its costs are 1) and still counts in
    its scenario's mean, so failing is never better than driving badly. ``exclude``: failed
    episodes are left out of the means and only listed in the report."""

    def __post_init__(self) -> None:
        _check(self, "<MetricParams>")

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any] | None, source: str = "<dict>"
    ) -> MetricParams:
        """Build from a (possibly partial) nested mapping; unknown keys and bad values raise."""
        return _build(cls, data or {}, source, "")

    def to_dict(self) -> dict[str, Any]:
        return _to_dict(self)


def load_params(path: str | os.PathLike | None = None) -> MetricParams:
    """Load metric constants from ``path``; with None, from the repository config if present.

    An installed package without the repository's ``configs/`` falls back to the defaults, which
    equal that file's contents (a test keeps the two in step).
    """
    if path is None:
        if not DEFAULT_CONFIG_PATH.is_file():
            return MetricParams()
        path = DEFAULT_CONFIG_PATH
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise MetricParamsError(
            f"{source}: cannot read metrics config: {exc.strerror or exc}"
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MetricParamsError(f"{source}: invalid YAML: {exc}") from None
    if data is not None and not isinstance(data, Mapping):
        raise MetricParamsError(
            f"{source}: expected a mapping at the top level, got {type(data).__name__}"
        )
    return MetricParams.from_dict(data, source=source)


# ------------------------------------------------------------------------------------ helpers
def _build(cls: type, data: Any, source: str, prefix: str) -> Any:
    if not isinstance(data, Mapping):
        raise MetricParamsError(
            f"{source}: {prefix.rstrip('.') or '<top>'}: expected a mapping, got {data!r}"
        )
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise MetricParamsError(
            f"{source}: unknown key {prefix}{unknown[0]} (known: {', '.join(sorted(known))})"
        )
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        default = getattr(cls(), name)
        key = f"{prefix}{name}"
        if is_dataclass(default):
            kwargs[name] = _build(type(default), value, source, f"{key}.")
        elif isinstance(default, str):
            if value not in FAILED_EPISODE_POLICIES:
                raise MetricParamsError(
                    f"{source}: {key}: expected one of {', '.join(FAILED_EPISODE_POLICIES)}, got {value!r}"
                )
            kwargs[name] = value
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise MetricParamsError(
                    f"{source}: {key}: expected a number, got {value!r}"
                )
            kwargs[name] = float(value)
    try:
        obj = cls(**kwargs)
    except MetricParamsError as exc:
        raise MetricParamsError(str(exc).replace("<MetricParams>", source)) from None
    if cls is not MetricParams:
        _check(obj, source, prefix)
    return obj


def _check(obj: Any, source: str, prefix: str = "") -> None:
    """Range checks: weights >= 0, penalty period >= 0, every other constant > 0, all finite."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        key = f"{prefix}{f.name}"
        if is_dataclass(value):
            _check(value, source, f"{key}.")
            continue
        if isinstance(value, str):
            if value not in FAILED_EPISODE_POLICIES:
                raise MetricParamsError(
                    f"{source}: {key}: expected one of {', '.join(FAILED_EPISODE_POLICIES)}, got {value!r}"
                )
            continue
        zero_ok = isinstance(obj, Weights) or f.name == "penalty_period_s"
        if not math.isfinite(value) or value < 0 or (value == 0 and not zero_ok):
            need = ">= 0" if zero_ok else "> 0"
            raise MetricParamsError(
                f"{source}: {key}: expected a finite number {need}, got {value!r}"
            )
    if isinstance(obj, Weights):
        base = obj.pr + obj.rc + obj.humanness
        if base + obj.mte <= 0 or base + obj.sfd <= 0:
            raise MetricParamsError(
                f"{source}: {prefix.rstrip('.') or 'weights'}: the weights of a task must not all be zero"
            )


def _to_dict(obj: Any) -> Any:
    if is_dataclass(obj):
        return {f.name: _to_dict(getattr(obj, f.name)) for f in fields(obj)}
    return obj
