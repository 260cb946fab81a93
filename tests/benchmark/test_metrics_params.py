"""Metric constants: the YAML config, its schema and validation."""

from __future__ import annotations

import pytest

from smarts.benchmark.metrics import (
    DEFAULT_CONFIG_PATH,
    MetricParams,
    MetricParamsError,
    Weights,
    load_params,
)


def test_config_file_equals_paper_defaults():
    assert DEFAULT_CONFIG_PATH.is_file()
    params = load_params()
    assert params == MetricParams()
    assert params.weights == Weights(pr=0.1, rc=0.45, humanness=0.15, mte=0.3, sfd=0.3)
    h = params.humanness
    assert (
        h.penalty_period_s,
        h.jerk_long_max,
        h.jerk_lat_max,
        h.accel_long_max,
        h.accel_lat_max,
    ) == (3.0, 0.9, 0.9, 2.0, 1.47)
    assert params.rules.overspeed_scale == 0.5 and h.lane_offset_scale == 0.5
    f = params.following
    assert (f.max_time_gap_s, f.safe_headway_s, f.standstill_distance_m) == (
        3.0,
        1.0,
        2.5,
    )
    assert params.failed_episodes == "worst"


def test_partial_override_keeps_other_defaults(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(
        "weights: {rc: 1}\nfollowing:\n  max_time_gap_s: 2\nfailed_episodes: exclude\n"
    )
    params = load_params(path)
    assert params.weights.rc == 1.0 and params.weights.pr == 0.1
    assert (
        params.following.max_time_gap_s == 2.0
        and params.following.safe_headway_s == 1.0
    )
    assert params.failed_episodes == "exclude"
    assert MetricParams.from_dict(params.to_dict()) == params


@pytest.mark.parametrize(
    "text, message",
    [
        ("weights: {pr: 0.1, rcc: 1}", "unknown key weights.rcc"),
        (
            "humanness: {jerk_long_max: 0}",
            "humanness.jerk_long_max: expected a finite number > 0",
        ),
        (
            "humanness: {penalty_period_s: -1}",
            "penalty_period_s: expected a finite number >= 0",
        ),
        ("rules: {overspeed_scale: fast}", "rules.overspeed_scale: expected a number"),
        (
            "weights: {pr: 0, rc: 0, humanness: 0, mte: 0}",
            "weights of a task must not all be zero",
        ),
        ("failed_episodes: ignore", "failed_episodes: expected one of worst, exclude"),
        ("following: 3", "following: expected a mapping"),
        ("- a list", "expected a mapping at the top level"),
        ("weights: {pr: .nan}", "weights.pr: expected a finite number"),
    ],
)
def test_invalid_configs_name_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MetricParamsError, match=message) as err:
        load_params(path)
    assert str(path) in str(err.value)


def test_direct_construction_is_validated():
    with pytest.raises(MetricParamsError, match="weights.rc"):
        MetricParams(weights=Weights(rc=-1.0))
    with pytest.raises(MetricParamsError, match="cannot read"):
        load_params("/nonexistent/metrics.yaml")
