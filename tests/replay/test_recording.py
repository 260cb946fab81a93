"""The recording arrays on their own: grouping samples into tracks, gaps, interpolation, windows."""

from __future__ import annotations

import numpy as np
import pytest

from smarts.core.errors import ScenarioError
from smarts.core.spec.replay import ReplaySpec
from smarts.replay.load import check_capacity, most_at_once, plan_replay
from smarts.replay.recording import from_samples
from tests.replay.files import three_vehicles, write_ngsim


def _rec(ids, frames, x, y, heading=None, speed=None):
    n = len(ids)
    return from_samples("mem", "test", np.array(ids), np.array(frames), np.array(x, float), np.array(y, float),
                        None if heading is None else np.array(heading, float),
                        None if speed is None else np.array(speed, float),
                        np.full(n, 4.0), np.full(n, 2.0), np.zeros(n, np.int8), 0.1)  # fmt: skip


def test_samples_in_any_order_become_one_track_per_vehicle_with_gaps_filled():
    rec = _rec(["b", "a", "a", "b", "a"], [7, 3, 0, 5, 1], [50.0, 3.0, 0.0, 40.0, 1.0], [0, 0, 0, 0, 0],
               heading=[0, 0, 0, 0, 0], speed=[5, 10, 10, 5, 10])  # fmt: skip
    assert rec.ids == ["a", "b"] and rec.first.tolist() == [0, 5] and rec.count.tolist() == [4, 3]
    np.testing.assert_allclose(rec.track(0)[:, 0], [0.0, 1.0, 2.0, 3.0])  # frame 2 was missing
    np.testing.assert_allclose(rec.track(1)[:, 0], [40.0, 45.0, 50.0])  # frame 6 was missing


def test_interpolation_is_exact_at_frames_and_takes_the_short_way_round_in_heading():
    rec = _rec(["a", "a", "a"], [10, 11, 12], [0.0, 1.0, 3.0], [0.0, 0.0, 0.0], heading=[3.1, -3.1, -3.1],
               speed=[10.0, 20.0, 20.0])  # fmt: skip
    present, st = rec.state_at(11.0)
    assert present.tolist() == [True] and st[:, 0].tolist() == pytest.approx([1.0, 0.0, -3.1, 20.0])
    _, st = rec.state_at(10.5)
    assert st[0, 0] == pytest.approx(0.5) and st[3, 0] == pytest.approx(15.0)
    assert abs(st[2, 0]) == pytest.approx(np.pi, abs=1e-9)  # across +-pi, not through 0
    assert rec.state_at(9.5)[0].tolist() == [False] and rec.state_at(12.5)[0].tolist() == [False]
    assert np.isnan(rec.state_at(13.0)[1]).all()


def test_heading_from_positions_holds_while_standing_still():
    x = [0.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0]
    y = [0.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0]
    rec = _rec(["a"] * 7, range(7), x, y)
    np.testing.assert_allclose(rec.track(0)[:, 2], np.pi / 4, atol=1e-9)
    assert rec.track(0)[-1, 3] == pytest.approx(0.0)


def test_most_at_once_and_the_capacity_check(tmp_path):
    write_ngsim(tmp_path / "traj.csv", three_vehicles())
    plan = plan_replay(ReplaySpec(format="ngsim", path="traj.csv"), tmp_path, "s.yaml")
    rec = plan.recording
    assert most_at_once(rec) == 3
    assert most_at_once(rec, 5.0) == 2  # vehicle 3 left at 4.9 s
    assert most_at_once(rec, 0.0, 0.5) == 1
    check_capacity(plan, 4, 1, "s.yaml")
    with pytest.raises(ScenarioError, match=r"s.yaml: vehicle_capacity: the replay has up to 3 vehicles at once .* "
                                            r"expected at least 4, got 3"):  # fmt: skip
        check_capacity(plan, 3, 1, "s.yaml")
