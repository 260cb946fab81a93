"""The episode log format: round trips, exports and clear errors on malformed logs."""

from __future__ import annotations

import csv
import json
import math
import pickle

import numpy as np
import pytest

from smarts.benchmark.metrics import (
    REQUIRED_COLUMNS,
    AgentTrace,
    LogError,
    episode_filename,
    export_csv,
    export_jsonl,
    read_episode,
    read_episodes,
    score_episode,
    write_episode,
)
from smarts.benchmark.metrics.__main__ import main as cli_main
from smarts.benchmark.metrics.synthetic import make_episode, make_trace


def _adaptive_log():
    follow = make_trace(6, with_following=True, extra={"steering": np.linspace(-0.1, 0.1, 6)})
    follow.follow_time_gap[2] = np.nan
    follow.lead_in_lane_and_visible[2] = False
    off = np.array([False, False, False, False, True, True])
    other = make_trace(
        6,
        with_following=True,
        off_road=off,
        lane_offset=np.where(off, np.nan, 0.3),
        lane_width=np.where(off, np.nan, 3.5),
    )
    other.follow_time_gap[:] = np.inf
    return make_episode(
        {"ego/0": follow, "ego 1": other},
        scenario="platoon: merge",
        task="adaptive",
        episode=3,
        seed=None,
        initial_route_distance={"ego/0": 100.0, "ego 1": 80.0},
        info={"agent": "zoo:keep-lane", "action_space": "RelativeTargetPose"},
    )


def _rewrite(path, drop=(), replace=None):
    """Rewrite an .npz bypassing validation, as a foreign or buggy writer could."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k not in drop}
    arrays.update(replace or {})
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def test_round_trip(tmp_path):
    log = _adaptive_log()
    path = write_episode(log, tmp_path / episode_filename(log))
    assert path.name == "platoon__merge__ep00003.npz"
    back = read_episode(path)
    assert back == log
    assert back.source == str(path)
    assert back.agent_ids == ["ego/0", "ego 1"]
    assert back.seed is None and back.failure is None and back.info == log.info
    assert back.agents["ego/0"].extra["steering"].tolist() == log.agents["ego/0"].extra["steering"].tolist()
    assert back.agents["ego 1"].wrong_way.dtype == np.bool_
    assert math.isinf(back.agents["ego 1"].follow_time_gap[0])
    assert score_episode(back) == score_episode(log)
    # No pickles: every stored array loads with allow_pickle=False and the metadata is JSON.
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["metadata"]))
    assert meta["version"] == 2 and meta["task"] == "adaptive"


def test_round_trip_collaborative_without_following_columns(tmp_path):
    log = make_episode({"a": make_trace(4)}, failure=None, seed=7)
    back = read_episode(write_episode(log, tmp_path / "x.npz"))
    assert back == log and back.agents["a"].follow_time_gap is None and back.seed == 7
    failed = make_episode({"a": AgentTrace.empty()}, task="adaptive", failure="agent raised ValueError")
    back = read_episode(write_episode(failed, tmp_path / "failed.npz"))
    assert back.failure == "agent raised ValueError" and back.agents["a"].num_steps == 0


def test_read_episodes_from_folder(tmp_path):
    for ep in (1, 0):
        log = make_episode({"a": make_trace(3)}, episode=ep)
        write_episode(log, tmp_path / "runs" / episode_filename(log))
    logs = read_episodes(tmp_path)
    assert [log.episode for log in logs] == [0, 1]


def test_exports(tmp_path):
    log = _adaptive_log()
    lines = export_jsonl(log, tmp_path / "log.jsonl").read_text().splitlines()
    assert len(lines) == 12
    row = json.loads(lines[2])
    assert row["agent"] == "ego/0" and row["step"] == 2 and row["follow_time_gap"] is None
    assert row["extra.steering"] == pytest.approx(log.agents["ego/0"].extra["steering"][2])
    with open(export_csv(log, tmp_path / "log.csv"), newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 12 and rows[0]["scenario"] == "platoon: merge"
    assert float(rows[7]["speed"]) == 10.0 and rows[7]["agent"] == "ego 1"
    assert rows[11]["off_road"] == "True" and rows[11]["lane_offset"] == "nan"


def test_missing_column_in_file_names_file_agent_column(tmp_path):
    path = write_episode(make_episode({"a": make_trace(3), "b": make_trace(3)}), tmp_path / "e.npz")
    _rewrite(path, drop=("agents/1/lane_width",))
    with pytest.raises(LogError) as err:
        read_episode(path)
    assert (err.value.source, err.value.agent, err.value.column) == (
        str(path),
        "b",
        "lane_width",
    )
    assert str(path) in str(err.value) and "missing column" in str(err.value)


def test_nan_speed_in_file_and_in_memory(tmp_path):
    path = write_episode(make_episode({"a": make_trace(5)}), tmp_path / "e.npz")
    speed = np.array([10.0, 10.0, np.nan, 10.0, 10.0])
    _rewrite(path, replace={"agents/0/speed": speed})
    with pytest.raises(
        LogError,
        match=r"e\.npz: agent 'a': column 'speed': non-finite value nan at step 2",
    ):
        read_episode(path)
    log = make_episode({"a": make_trace(5)})
    log.agents["a"].speed[2] = np.nan
    with pytest.raises(LogError, match=r"<in-memory log>: agent 'a': column 'speed'"):
        score_episode(log)
    with pytest.raises(LogError):
        write_episode(log, tmp_path / "never.npz")
    assert not (tmp_path / "never.npz").exists()


def test_mismatched_lengths(tmp_path):
    path = write_episode(make_episode({"a": make_trace(5)}), tmp_path / "e.npz")
    _rewrite(path, replace={"agents/0/heading": np.zeros(4)})
    with pytest.raises(LogError) as err:
        read_episode(path)
    assert err.value.column == "heading" and "'time' has 5" in str(err.value)
    trace = make_trace(5, extra={"steering": np.zeros(6)})
    with pytest.raises(LogError, match="column 'extra.steering'"):
        score_episode(make_episode({"a": trace}))


@pytest.mark.parametrize(
    "change, column, message",
    [
        (
            {"lane_offset": np.array([0.0, np.nan, 0.0])},
            "lane_offset",
            "off_road is false",
        ),
        ({"time": np.array([0.1, 0.1, 0.3])}, "time", "strictly increasing"),
        ({"speed_limit": np.array([20.0, 0.0, 20.0])}, "speed_limit", "> 0"),
        (
            {"route_distance_to_goal": np.array([5.0, -1.0, 0.0])},
            "route_distance_to_goal",
            ">= 0",
        ),
        ({"off_road": np.array([0, 1, 0])}, "off_road", "expected booleans"),
        ({"x": np.zeros((3, 2))}, "x", "1-D"),
        (
            {"follow_time_gap": np.array([1.0, np.nan, 1.0])},
            "follow_time_gap",
            "not NaN",
        ),
    ],
)
def test_invalid_columns(change, column, message):
    trace = make_trace(3, with_following=True, **change)
    with pytest.raises(LogError, match=message) as err:
        score_episode(make_episode({"car": trace}, task="adaptive"))
    assert err.value.agent == "car" and err.value.column == column


def test_following_columns_required_for_adaptive_task():
    log = make_episode({"car": make_trace(3)}, task="adaptive")
    with pytest.raises(LogError, match="required for the adaptive task") as err:
        score_episode(log)
    assert err.value.column == "follow_time_gap"


def test_bad_metadata(tmp_path):
    with pytest.raises(LogError, match="metadata.task"):
        score_episode(make_episode({"a": make_trace(3)}, task="racing"))
    with pytest.raises(LogError, match="metadata.dt"):
        score_episode(make_episode({"a": make_trace(3)}, dt=0.0))
    with pytest.raises(LogError, match="metadata.initial_route_distance"):
        score_episode(make_episode({"a": make_trace(3)}, initial_route_distance={"b": 1.0}))
    with pytest.raises(LogError, match="no steps logged"):
        score_episode(make_episode({"a": AgentTrace.empty()}))
    path = write_episode(make_episode({"a": make_trace(3)}), tmp_path / "e.npz")
    meta = {"format": "smarts-episode-log", "version": 99}
    _rewrite(path, replace={"metadata": np.array(json.dumps(meta))})
    with pytest.raises(LogError, match="unsupported version 99"):
        read_episode(path)


def test_pickled_or_garbage_files_are_refused(tmp_path):
    path = tmp_path / "pickled.npz"
    with open(path, "wb") as fh:
        np.savez(fh, metadata=np.array([{"evil": 1}], dtype=object))
    with pytest.raises(LogError, match="not a readable"):
        read_episode(path)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(LogError, match="junk.npz"):
        read_episode(junk)


def test_every_required_column_is_checked():
    for column in REQUIRED_COLUMNS:
        trace = make_trace(3)
        setattr(trace, column, None)
        with pytest.raises(LogError, match=f"column '{column}': missing column"):
            score_episode(make_episode({"a": trace}))


def test_cli_scores_a_folder(tmp_path, capsys):
    for ep in range(2):
        write_episode(make_episode({"a": make_trace(3)}, episode=ep), tmp_path / f"e{ep}.npz")
    assert cli_main([str(tmp_path)]) == 0
    assert "overall" in capsys.readouterr().out
    assert cli_main([str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["episodes"] == {"scenario": 2} and set(out["overall"]) >= {
        "PR",
        "S_bench",
    }
    (tmp_path / "empty").mkdir()
    assert cli_main([str(tmp_path / "empty")]) == 2
    assert "no .npz" in capsys.readouterr().err


def test_cli_scores_each_agent_of_a_benchmark_logs_folder(tmp_path, capsys):
    # The runner's layout: logs/<agent>/<scenario>/episode_000.npz, every agent the same episodes.
    logs = tmp_path / "logs"
    for agent, steps in (("zoo:keep-lane", 3), ("zoo:random", 5)):
        for ep in range(2):
            log = make_episode({"a": make_trace(steps)}, episode=ep, info={"agent": agent})
            write_episode(log, logs / agent.replace(":", "_") / "scenario" / f"episode_{ep:03d}.npz")
    assert cli_main([str(logs)]) == 0
    out = capsys.readouterr().out
    assert out.count("overall") == 2
    assert out.index("agent: zoo:keep-lane") < out.index("agent: zoo:random")
    assert cli_main([str(logs), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["agents"]
    assert [(r["agent"], r["task"], r["scores"]["episodes"]) for r in rows] == [
        ("zoo:keep-lane", "collaborative", {"scenario": 2}),
        ("zoo:random", "collaborative", {"scenario": 2}),
    ]
    # Each agent is scored alone: its scores are those of its own folder.
    assert cli_main([str(logs / "zoo_random"), "--json"]) == 0
    alone = json.loads(capsys.readouterr().out)
    assert alone["overall"] == rows[1]["scores"]["overall"]
    # One agent's episode twice is still an error.
    write_episode(
        make_episode({"a": make_trace(3)}, episode=0, info={"agent": "zoo:random"}),
        logs / "copy" / "episode_000.npz",
    )
    assert cli_main([str(logs)]) == 2
    assert "episode 0 of scenario 'scenario' appears twice" in capsys.readouterr().err


def test_log_error_survives_pickling():
    err = LogError("missing column", source="runs/e.npz", agent="a", column="speed")
    back = pickle.loads(pickle.dumps(err))
    assert str(back) == str(err) == "runs/e.npz: agent 'a': column 'speed': missing column"
    assert (back.source, back.agent, back.column) == ("runs/e.npz", "a", "speed")


def test_rows_follow_the_step_contract():
    # Row k is the state after step k+1: a row at time 0 is the reset state and is refused.
    trace = make_trace(3, time=np.array([0.0, 0.1, 0.2]))
    with pytest.raises(LogError, match="reset state is not a row") as err:
        score_episode(make_episode({"a": trace}))
    assert err.value.column == "time"
    # No row after the time limit: a late arrival cannot count for PR (nor for MTE).
    late = np.zeros(12, dtype=bool)
    late[-1] = True
    trace = make_trace(12, goal_reached=late)  # the last row is at 1.2 s
    with pytest.raises(LogError, match=r"row 11 at 1.2.* after the time limit 1.1") as err:
        score_episode(make_episode({"a": trace}, time_limit=1.1))
    assert err.value.agent == "a" and err.value.column == "time"
    ok = make_episode({"a": make_trace(11, goal_reached=late[1:])}, time_limit=1.1)
    assert score_episode(ok)["PR"] == 1.0  # arriving on the limit's own step counts
    # Float noise in the clock is tolerated.
    noisy = make_trace(11, time=0.1 * np.arange(1, 12) + 1e-9)
    score_episode(make_episode({"a": noisy}, time_limit=1.1))
