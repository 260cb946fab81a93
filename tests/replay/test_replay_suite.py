"""``smarts replay suite``: a folder of recordings becomes a benchmark suite of take-over scenarios,
read by the suite loader and run end to end by ``python -m train benchmark``."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from smarts.__main__ import main
from smarts.benchmark.suites import load_suite
from tests.replay.files import (
    av2_tracks,
    three_vehicles,
    waymo_junction,
    waymo_scenario,
    write_av2,
    write_ngsim,
    write_waymo,
)


def test_a_folder_of_waymo_files_becomes_a_suite_that_the_benchmark_runs(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    write_waymo(logs / "training.tfrecord-00000-of-00002", [waymo_junction(), waymo_scenario("second")])
    write_waymo(logs / "training.tfrecord-00001-of-00002", [waymo_junction("third", jitter=False)])
    (logs / "notes.txt").write_text("not a recording")  # other files are not read
    out = tmp_path / "suites" / "womd.yaml"
    assert (
        main(["replay", "suite", str(logs), "--format", "waymo", "--out", str(out), "--reactive", "interaction"]) == 0
    )
    assert "wrote" in capsys.readouterr().out
    data = yaml.safe_load(out.read_text())
    assert data["task"] == "collaborative" and data["name"] == "womd"
    names = [s["name"] for s in data["scenarios"]]
    assert names == ["training_7a6b5c4d3e2f1a0b_1", "training_second_7", "training_third_1"]
    first = data["scenarios"][0]
    assert first["scenario"]["replay"] == {
        "format": "waymo", "path": "../logs/training.tfrecord-00000-of-00002", "scenario": "7a6b5c4d3e2f1a0b",
        "reactive": "interaction", "take_over": {"ego": "1"}, "start": 0.0,
    }  # fmt: skip
    assert first["scenario"]["map"] == "replay" and first["difficulty"] == "easy"
    assert first["time_limit"] == pytest.approx(8.9991 * 1.5 + 2.0, abs=0.1)
    suite = load_suite(out)  # the benchmark's own reader, paths relative to the suite file
    assert [s.name for s in suite.scenarios] == names
    assert suite.scenarios[1].spec.replay.take_over == {"ego": "7"}

    from train.__main__ import main as train_main

    bench = tmp_path / "bench"
    code = train_main(["benchmark", "--suite", str(out), "--agent", "zoo:keep-lane", "--workers", "1", "--out",
                       str(bench), "--quiet"])  # fmt: skip
    assert code == 0
    results = json.loads((bench / "results.json").read_text())
    assert results["complete"] and results["failures"] == [] and results["episodes_not_run"] == 0
    # keep-lane and the two other reference agents, each on the three scenarios, scored
    assert set(results["agents"]) == {"zoo:keep-lane", "zoo:random", "zoo:stand-still"}
    keep_lane = results["agents"]["zoo:keep-lane"]["scores"]
    assert set(keep_lane["scenarios"]) == set(names)
    assert keep_lane["overall"]["PR"] == 1.0  # it drives each recorded ego's route to its end
    assert len(list((bench / "logs").rglob("episode_000.npz"))) == 9 and (bench / "report.md").is_file()

    # and trainable: --suite trains on every scenario of it and evaluates on it
    run = tmp_path / "run"
    code = train_main(["ppo", "--task", "drive", "--suite", str(out), "--total-steps", "128", "--envs", "3",
                       "--workers", "0", "--frames-per-batch", "64", "--minibatch-size", "32", "--epochs", "1",
                       "--eval-episodes", "1", "--eval-workers", "1", "--out-dir", str(run), "--quiet"])  # fmt: skip
    assert code == 0
    config = json.loads((run / "config.json").read_text())
    assert config["scenarios"] == [f"{out}:*"] and config["eval_suite"] == str(out)
    trained = json.loads((run / "eval" / "results.json").read_text())
    assert set(trained["agents"]["zoo:keep-lane"]["scores"]["scenarios"]) == set(names)


def test_argoverse2_and_ngsim_folders_and_what_is_left_out(tmp_path, capsys):
    from smarts.scenario.builtin_maps import builtin_map_path

    scenes = tmp_path / "av2"
    write_av2(scenes / "scene_a")
    rows = av2_tracks()
    for r in rows:  # here the AV drives off the cropped map's end (x 200) to x 451
        if r["track_id"] == "AV":
            r["position_x"] = 5.0 + (451.0 - 5.0) * r["timestep"] / 109
    write_av2(scenes / "scene_b", tracks=rows)
    out = tmp_path / "av2.yaml"
    assert main(["replay", "suite", str(scenes), "--format", "argoverse2", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "skipped scene_b: " in err and "vehicle 'AV' ends at (451.0, 1.8), which is off the map" in err
    suite = load_suite(out)
    assert [s.name for s in suite.scenarios] == ["scene_a_AV"]
    assert suite.scenarios[0].spec.replay.path == "av2/scene_a"
    # asking for a vehicle that stays on the map takes it over where the AV cannot be
    assert main(["replay", "suite", str(scenes), "--format", "argoverse2", "--out", str(out), "--vehicle", "11"]) == 0
    assert [s.name for s in load_suite(out).scenarios] == ["scene_a_11", "scene_b_11"]
    # NGSIM has no map of its own: the site's map is named, and the longest-recorded vehicle is taken over
    ngsim = tmp_path / "ngsim"
    ngsim.mkdir()
    write_ngsim(ngsim / "trajectories-0400-0415.csv", three_vehicles())
    shutil.copy(builtin_map_path("straight_2lane"), tmp_path / "site.net.xml")
    out = tmp_path / "ngsim.yaml"
    assert main(["replay", "suite", str(ngsim), "--format", "ngsim", "--out", str(out), "--swap-xy", "--flip-y"]) == 2
    assert "--map: NGSIM recordings have no map of their own" in capsys.readouterr().err
    assert main(["replay", "suite", str(ngsim), "--format", "ngsim", "--out", str(out), "--swap-xy", "--flip-y",
                 "--map", str(tmp_path / "site.net.xml")]) == 0  # fmt: skip
    entry = load_suite(out).scenarios[0]
    assert entry.name == "trajectories-0400-0415_2" and entry.spec.map == "site.net.xml"
    assert entry.spec.replay.start == pytest.approx(1.0) and entry.time_limit == pytest.approx(7.9 * 1.5 + 2.0, abs=0.1)
    # a folder with nothing to take over is one error naming each reason
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["replay", "suite", str(empty), "--format", "waymo", "--out", str(tmp_path / "none.yaml")]) == 2
    assert "no scenario to take over in the waymo recordings" in capsys.readouterr().err
