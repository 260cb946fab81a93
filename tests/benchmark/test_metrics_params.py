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
    path.write_text("weights: {rc: 1}\nfollowing:\n  max_time_gap_s: 2\nfailed_episodes: exclude\n")
    params = load_params(path)
    assert params.weights.rc == 1.0 and params.weights.pr == 0.1
    assert params.following.max_time_gap_s == 2.0 and params.following.safe_headway_s == 1.0
    assert params.failed_episodes == "exclude"
    assert MetricParams.from_dict(params.to_dict()) == params


@pytest.mark.parametrize(
    "text, message",
    [
        ("weights: {pr: 0.1, rcc: 1}", "weights.rcc: unknown field; did you mean 'rc'"),
        (
            "humanness: {jerk_long_max: 0}",
            "humanness.jerk_long_max: input should be greater than 0",
        ),
        (
            "humanness: {penalty_period_s: -1}",
            "penalty_period_s: input should be greater than or equal to 0",
        ),
        ("rules: {overspeed_scale: fast}", "rules.overspeed_scale: input should be a valid number"),
        ("weights: {pr: true}", "weights.pr: input should be a valid number"),
        (
            "weights: {pr: 0, rc: 0, humanness: 0, mte: 0}",
            "weights of a task must not all be zero",
        ),
        ("failed_episodes: ignore", "failed_episodes: input should be 'worst' or 'exclude'"),
        ("following: 3", "following: input should be a valid dictionary"),
        ("- a list", "expected a mapping at the top level"),
        ("weights: {pr: .nan}", "weights.pr: input should be a finite number"),
    ],
)
def test_invalid_configs_name_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MetricParamsError, match=message) as err:
        load_params(path)
    assert str(path) in str(err.value)


def test_direct_construction_is_validated():
    with pytest.raises(ValueError, match="rc"):  # pydantic's ValidationError is a ValueError
        MetricParams(weights=Weights(rc=-1.0))
    with pytest.raises(ValueError, match="frozen"):
        MetricParams().weights.pr = 2.0
    with pytest.raises(MetricParamsError, match="cannot read"):
        load_params("/nonexistent/metrics.yaml")
