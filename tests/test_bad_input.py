"""Bad input, as users give it, through the command lines they use: every case ends with exit code
2 (``smarts.exit_codes.BAD_INPUT``, the same for every command), one message naming the file,
field, flag or agent at fault and what was expected, no traceback, and nothing written where it
should not be.

The per-module tests check the messages in detail; this corpus checks the joints: that each error
reaches the user through the CLI intact."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("bad")
    made = {
        "garbage.pt": b"not a checkpoint",
        "half.net.xml": b'<?xml version="1.0"?><net version="1.20"><edge id="a"',
        "typo.yaml": b"name: x\nmap: builtin:straight_2lane\nagents:\n"
        b"  - mission: {start: {road: main, ofset: 3}, goal: {road: main, offset: 50}}\n",
        "strict.yaml": b"name: x\nmap: builtin:straight_2lane\nepisode_steps: true\nagents:\n"
        b"  - mission: {start: {road: main, offset: 3}, goal: {road: main, offset: 50}}\n",
        "no_map.yaml": b"name: x\nmap: missing.net.xml\nagents:\n"
        b"  - mission: {start: {road: main, offset: 3}, goal: {road: main, offset: 50}}\n",
        "not_yaml.yaml": b"name: [unclosed\n",
        "log.npz": b"PK not really a log",
        "suite.yaml": b"task: adaptive\nepisodes: 0\nscenarioz: []\n",
        "train.yaml": b"task: platoon\nlr: 0.001\nepochz: 3\n",
    }
    made["behind.yaml"] = (b"name: x\nmap: builtin:straight_2lane\nagents:\n"
                           b"  - mission: {start: {road: main, offset: 50}, goal: {road: main, offset: 10}}\n")  # fmt: skip
    paths = {}
    for name, data in made.items():
        (tmp / name).write_bytes(data)
        paths[name] = tmp / name
    for name, edit in CHECKPOINT_EDITS.items():  # shipped checkpoints, edited in memory
        import torch

        blob = torch.load(ROOT / "zoo" / "checkpoints" / "drive.pt", weights_only=True)
        edit(blob)
        torch.save(blob, tmp / name)
        paths[name] = tmp / name
    paths["tmp"] = tmp
    return paths


CHECKPOINT_EDITS = {
    "no_space.pt": lambda blob: blob["action"].pop("space"),
    "huge.pt": lambda blob: blob.update(hidden=[10**9]),
    "nan_bounds.pt": lambda blob: blob["action"]["low"].__setitem__(0, float("nan")),
}


CASES = [
    # (name, command line with {file} placeholders, fragments the last stderr lines must hold)
    (
        "checkpoint that is not one",
        ["-m", "train", "eval", "--agent", "{garbage.pt}", "--suite", "adaptive"],
        ["garbage.pt: not a readable checkpoint"],
    ),
    (
        "resume from a non-checkpoint",
        ["-m", "train", "ppo", "--task", "platoon", "--resume", "{garbage.pt}", "--out-dir", "{tmp}/resumed"],
        ["garbage.pt: not a readable checkpoint"],
    ),
    (
        "unknown action space flag",
        ["-m", "train", "ppo", "--task", "platoon", "--action-space", "warp", "--out-dir", "{tmp}/warp"],
        ["--action-space: action_space:", "'warp'"],
    ),
    (
        "training YAML with a typo",
        ["-m", "train", "ppo", "--config", "{train.yaml}", "--out-dir", "{tmp}/typo"],
        ["train.yaml: epochz: unknown field; did you mean 'epochs'?"],
    ),
    (
        "zero benchmark episodes",
        ["-m", "train", "benchmark", "--suite", "adaptive", "--episodes", "0"],
        ["--episodes must be >= 1"],
    ),
    ("unknown suite", ["-m", "train", "benchmark", "--suite", "nope"], ["unknown benchmark suite 'nope'"]),
    (
        "suite file with errors",
        ["-m", "train", "benchmark", "--suite", "{suite.yaml}"],
        ["suite.yaml: episodes:", "scenarioz: unknown field; did you mean 'scenarios'?"],
    ),
    (
        "unknown agent locator",
        ["-m", "train", "benchmark", "--suite", "adaptive", "--agent", "zoo:nobody"],
        ["zoo:nobody"],
    ),
    (
        "scenario with a misspelt field",
        ["-m", "smarts", "scenario", "show", "{typo.yaml}"],
        ["typo.yaml: agents[0].mission.start.ofset: unknown field; did you mean 'offset'?"],
    ),
    (
        "scenario with a bool for a count",
        ["-m", "smarts", "scenario", "show", "{strict.yaml}"],
        ["strict.yaml: episode_steps:"],
    ),
    (
        "scenario whose map file is missing",
        ["-m", "smarts", "scenario", "show", "--build", "{no_map.yaml}"],
        ["missing.net.xml"],
    ),
    ("scenario that is not YAML", ["-m", "smarts", "scenario", "show", "{not_yaml.yaml}"], ["not_yaml.yaml"]),
    ("episode log that is not one", ["-m", "smarts.benchmark.metrics", "{log.npz}"], ["log.npz"]),
    (
        "checkpoint without its action space",
        ["-m", "train", "eval", "--agent", "{no_space.pt}", "--suite", "collaborative"],
        ["no_space.pt: action.space: required field missing"],
    ),
    (
        "checkpoint asking for a 10**9-unit layer",
        ["-m", "train", "eval", "--agent", "{huge.pt}", "--suite", "collaborative"],
        ["huge.pt: hidden[0]: input should be less than or equal to 8192, got 1000000000"],
    ),
    (
        "checkpoint with a NaN action bound",
        ["-m", "train", "eval", "--agent", "{nan_bounds.pt}", "--suite", "collaborative"],
        ["nan_bounds.pt: action.low[0]: input should be a finite number, got nan"],
    ),
    (
        "goal behind the start on a one-way road",
        ["-m", "smarts", "scenario", "show", "--build", "{behind.yaml}"],
        ["behind.yaml: agents[0].mission.goal: offset 10 on road 'main' is not ahead of the start (offset 50"],
    ),
    (
        "training into a folder that cannot be made",
        ["-m", "train", "ppo", "--task", "platoon", "--out-dir", "{garbage.pt}/run"],
        ["run folder", "garbage.pt/run: cannot be made there"],
    ),
    (
        "benchmark into a folder that cannot be made",
        ["-m", "train", "benchmark", "--suite", "adaptive", "--out", "{garbage.pt}/b"],
        ["output folder", "garbage.pt/b: cannot be made there"],
    ),
]


@pytest.mark.parametrize("name, command, fragments", CASES, ids=[c[0] for c in CASES])
def test_bad_input_names_its_source_without_a_traceback(files, name, command, fragments):
    args = []
    for part in command:
        for key, path in files.items():
            part = part.replace("{" + key + "}", str(path))
        args.append(part)
    result = run(*args, cwd=files["tmp"])
    assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    for fragment in fragments:
        assert fragment in result.stderr, (name, fragment, result.stderr[-2000:])
    for folder in ("resumed", "warp", "typo"):  # a refused run leaves no folder behind
        assert not (files["tmp"] / folder).exists()


def test_a_nan_action_names_the_agent_and_changes_nothing():
    import numpy as np

    from smarts.core.errors import ActionError
    from smarts.env import DrivingParallelEnv

    env = DrivingParallelEnv("intersection_4way_signal_right")
    obs, _ = env.reset(seed=0)
    before = (env.sim.time, env.sim.step_count)
    actions = {a: 0.4 * obs[a]["waypoints"][0, 1] for a in env.agents}
    bad = dict(actions)
    victim = env.agents[-1]
    bad[victim] = np.full_like(actions[victim], np.nan)
    with pytest.raises(ActionError, match=victim):
        env.step(bad)
    assert (env.sim.time, env.sim.step_count) == before
    env.step(actions)  # the env goes on as if the bad step had never been asked for
    env.close()


# ---------------------------------------------------------------------------- replay readers and views
@pytest.fixture(scope="module")
def replay_files(tmp_path_factory) -> dict[str, Path]:
    import struct

    from smarts.replay.tfrecord import masked_crc
    from tests.replay.files import NGSIM_HEADER, three_vehicles, write_ngsim

    tmp = tmp_path_factory.mktemp("replay_bad")
    paths = {"tmp": tmp, "traj.csv": write_ngsim(tmp / "traj.csv", three_vehicles())}
    lines = paths["traj.csv"].read_text().splitlines()
    last = lines[4].split(",")
    last[NGSIM_HEADER.index("Frame_ID")] = "300000000"
    gap = [lines[0], *lines[1:4], ",".join(last)]  # four rows of one vehicle, the last 30,000 s later
    (tmp / "gap.csv").write_text("\n".join(gap) + "\n")
    cells = lines[75].split(",")  # a row of vehicle 2, not the first vehicle
    cells[NGSIM_HEADER.index("Local_Y")] = "inf"
    (tmp / "inf.csv").write_text("\n".join([*lines[:75], ",".join(cells), *lines[76:]]) + "\n")
    length = struct.pack("<Q", 2**62)  # a 112-byte file whose one header claims 2**62 bytes
    (tmp / "huge.tfrecord").write_bytes(length + struct.pack("<I", masked_crc(length)) + bytes(100))
    for name in ("gap.csv", "inf.csv", "huge.tfrecord"):
        paths[name] = tmp / name
    return paths


SHOW = ["-m", "smarts", "replay", "show", "{traj.csv}", "--format", "ngsim", "--out", "{tmp}/out.png"]
REPLAY_CASES = [
    ("replay show --fps 0", [*SHOW, "--fps", "0"], ["--fps: input should be greater than 0, got 0.0"]),
    ("replay show --fps -5", [*SHOW, "--fps", "-5"], ["--fps: input should be greater than 0, got -5.0"]),
    ("replay show --fps 1e9", [*SHOW, "--fps", "1e9"], ["--fps: input should be less than or equal to 120"]),
    ("replay show --duration -3", [*SHOW, "--duration", "-3"], ["--duration: input should be greater than 0"]),
    ("replay show --width 0", [*SHOW, "--width", "0"], ["--width: input should be greater than or equal to 16"]),
    (
        "replay show --width 2000000",
        [*SHOW, "--width", "2000000"],
        ["--width: input should be less than or equal to 4096"],
    ),
    ("replay show --offset nan 0", [*SHOW, "--offset", "nan", "0"], ["--offset[0]: input should be a finite number"]),
    (
        "replay info --offset inf 0",
        ["-m", "smarts", "replay", "info", "{traj.csv}", "--format", "ngsim", "--offset", "inf", "0"],
        ["--offset[0]: input should be a finite number"],
    ),
    ("replay show --time nan", [*SHOW, "--time", "nan"], ["--time: input should be a finite number"]),
    ("replay show --time past the end", [*SHOW, "--time", "60"], ["--time: the recording lasts 8.9 s, got 60"]),
    (
        "NGSIM rows with a frame gap",
        ["-m", "smarts", "replay", "info", "{gap.csv}", "--format", "ngsim"],
        ["gap.csv: vehicle '1' has no samples from frame 102 to frame 300000000"],
    ),
    (
        "NGSIM inf in a non-ego row",
        ["-m", "smarts", "replay", "info", "{inf.csv}", "--format", "ngsim"],
        ["inf.csv: column Local_Y: expected a finite number, got inf in data row 75"],
    ),
    (
        "TFRecord header claiming 2**62 bytes",
        ["-m", "smarts", "replay", "info", "{huge.tfrecord}", "--format", "waymo"],
        ["huge.tfrecord: record 0 at byte 0: truncated (the header claims 4611686018427387904 data bytes"],
    ),
    (
        "a folder read as Waymo",
        ["-m", "smarts", "replay", "info", "{tmp}", "--format", "waymo"],
        ["is a folder; --format waymo reads a TFRecord file of Scenario records"],
    ),
]


@pytest.mark.parametrize("name, command, fragments", REPLAY_CASES, ids=[c[0] for c in REPLAY_CASES])
def test_bad_replay_input_is_one_clear_error(replay_files, name, command, fragments):
    args = []
    for part in command:
        for key, path in replay_files.items():
            part = part.replace("{" + key + "}", str(path))
        args.append(part)
    result = run(*args, cwd=replay_files["tmp"])
    assert result.returncode == 2, (name, result.returncode, result.stdout[-1000:], result.stderr[-2000:])
    assert "Traceback" not in result.stderr and "MemoryError" not in result.stderr, result.stderr[-3000:]
    for fragment in fragments:
        assert fragment in result.stderr, (name, fragment, result.stderr[-2000:])
    assert not (replay_files["tmp"] / "out.png").exists()  # nothing drawn from refused options


# ---------------------------------------------------------------------------------- the viewer
def _viewer_folder(tmp: Path) -> dict[str, str]:
    """A folder with one good recording (written by the recorder) and bad ones beside it; bad file
    name -> what its warning must say."""
    import json

    import numpy as np

    from smarts.viz.recording import build_recording, write_recording
    from tests.viz.messages import scene

    reset = {"time": 0.0, "vehicle_ids": ["agent_0"], "vehicle_state": np.zeros((1, 6), np.float32),
             "vehicle_role": np.ones(1, np.int8), "vehicle_lane": np.zeros(1, np.int32),
             "signal_colour": np.zeros(0, np.int8), "agent_vehicle": np.zeros(1, np.int64), "agents": {}}  # fmt: skip
    meta = {"scenario": "hand_made", "seed": 0, "dt": 0.1}
    write_recording(build_recording([reset], ["agent_0"], scene(), meta), tmp / "good.rec.npz")
    (tmp / "empty.rec.npz").write_bytes(b"")
    np.savez(tmp / "list.rec.npz", metadata=np.array(json.dumps(["format"])), scene=np.array("{}"))
    return {"empty.rec.npz": "not a readable .npz", "list.rec.npz": "metadata is a JSON list"}


def test_viewer_names_an_unreadable_recording_it_is_given(tmp_path):
    for name, problem in _viewer_folder(tmp_path).items():
        result = run("-m", "smarts.viz", str(tmp_path / name), "--port", "0", cwd=tmp_path)
        assert result.returncode == 2, (name, result.returncode, result.stderr[-2000:])
        assert "Traceback" not in result.stderr, result.stderr[-3000:]
        assert f"error: {tmp_path / name}: " in result.stderr and problem in result.stderr, result.stderr[-2000:]


def test_viewer_skips_bad_recordings_in_a_folder_with_one_warning_each(tmp_path):
    import json
    import socket
    import time
    import urllib.request

    bad = _viewer_folder(tmp_path)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "smarts.viz", str(tmp_path), "--port", str(port)], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        started = proc.stdout.readline()
        assert "1 recorded episode(s)" in started, (started, proc.stderr.read() if proc.poll() is not None else "")
        listing = None
        for _ in range(300):
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/episodes", timeout=30) as r:
                    listing = json.loads(r.read())
                break
            except OSError:
                time.sleep(0.1)
        assert listing is not None and [e["name"] for e in listing["episodes"]] == ["good.rec.npz"]
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert "Traceback" not in err, err[-3000:]
    warnings = [line for line in err.splitlines() if line.startswith("warning: skipping")]
    assert len(warnings) == len(bad), err
    for name, problem in bad.items():
        assert any(f"{tmp_path / name}: " in w and problem in w for w in warnings), (name, warnings)


# ---------------------------------------------------------------------------- batched actions and step order
def _two_agent_copies(copies: int):
    from tests.builders import agent, make_spec

    spec = make_spec([agent(lane=0, offset=10.0), agent(lane=1, offset=10.0)], episode_steps=30)
    return [spec] * copies


def _escaped_shape(shape: tuple) -> str:
    import re

    return re.escape(str(tuple(shape)))


@pytest.mark.parametrize("copies, bad_shape", [(2, (12,)), (3, (3, 6))], ids=["flat-12-for-4x3", "3x6-for-6x3"])
def test_sb3_vec_env_refuses_actions_that_only_reshape_into_place(copies, bad_shape):
    """12 numbers for 4 slots of 3, or (3, 6) for (6, 3), hold the right count but not one row per
    slot: refused naming the expected shape, and no copy moves."""
    import numpy as np

    from smarts.core.errors import ActionError
    from smarts.env.sb3_vec_env import SmartsVecEnv

    vec = SmartsVecEnv(_two_agent_copies(copies), normalize_actions=True)
    try:
        vec.reset()
        slots = 2 * copies
        with pytest.raises(
            ActionError,
            match=rf"SmartsVecEnv: actions: expected shape \({slots}, 3\) .* got shape {_escaped_shape(bad_shape)}",
        ):
            vec.step(np.zeros(bad_shape, dtype=np.float32))
        assert vec.driving.groups[0].sim.episode_step.tolist() == [0] * copies
        vec.step(np.zeros((slots, 3), dtype=np.float32))
        assert vec.driving.groups[0].sim.episode_step.tolist() == [1] * copies
    finally:
        vec.close()


@pytest.mark.parametrize("adapter", ["SmartsVecEnv", "SmartsBatchedEnv", "BatchedDriving"])
def test_text_and_object_actions_are_one_clear_action_error(adapter):
    """Text, objects, bools or complex numbers as actions: an ``ActionError`` naming the dtype
    (not numpy's ``ufunc 'isfinite'`` TypeError), and nothing moves."""
    import numpy as np
    import torch

    from smarts.core.errors import ActionError
    from smarts.env.batched import BatchedDriving
    from smarts.env.sb3_vec_env import SmartsVecEnv
    from smarts.env.torchrl_env import SmartsBatchedEnv

    specs = _two_agent_copies(2)
    if adapter == "SmartsVecEnv":
        env = SmartsVecEnv(specs, normalize_actions=True)
        driving = env.driving
        env.reset()
        bad = [np.full((4, 3), "1.0"), np.full((4, 3), None, dtype=object), np.ones((4, 3), dtype=bool)]
        step = env.step
    elif adapter == "SmartsBatchedEnv":
        env = SmartsBatchedEnv(specs)
        driving = env.driving
        td = env.reset()
        bad = [torch.ones(4, 3, dtype=torch.bool), torch.ones(4, 3, dtype=torch.complex64)]

        def step(action):
            return env.step(td.clone().set("action", action))
    else:
        env = driving = BatchedDriving(specs)
        env.reset()
        bad = [np.full((4, 3), "1.0"), np.full((4, 3), None, dtype=object), np.ones((4, 3), dtype=bool)]
        step = env.step
    try:
        for action in bad:
            with pytest.raises(ActionError, match=r"actions: expected real numbers.*got dtype"):
                step(action)
        assert driving.groups[0].sim.episode_step.tolist() == [0, 0]
    finally:
        env.close()


@pytest.mark.parametrize("env_class", ["DrivingParallelEnv", "BatchedDriving", "SmartsBatchedEnv", "SmartsVecEnv"])
def test_step_before_reset_names_what_to_call(env_class):
    """Every env refuses a step before its first reset with the same words: which env, and that
    reset() comes first (the batched core used to step nothing and return zeros)."""
    import numpy as np

    from smarts.env import DrivingParallelEnv
    from smarts.env.batched import BatchedDriving
    from smarts.env.sb3_vec_env import SmartsVecEnv
    from smarts.env.torchrl_env import SmartsBatchedEnv

    specs = _two_agent_copies(2)
    if env_class == "DrivingParallelEnv":
        env = DrivingParallelEnv(specs[0])
        step = lambda: env.step({"agent_0": np.zeros(3), "agent_1": np.zeros(3)})  # noqa: E731
    elif env_class == "BatchedDriving":
        env = BatchedDriving(specs)
        step = lambda: env.step(np.zeros((4, 3)))  # noqa: E731
    elif env_class == "SmartsBatchedEnv":
        env = SmartsBatchedEnv(specs)
        step = lambda: env.step(env.full_action_spec.zero())  # noqa: E731
    else:
        env = SmartsVecEnv(specs)
        step = lambda: env.step(np.zeros((4, 3)))  # noqa: E731
    try:
        with pytest.raises(RuntimeError, match=rf"^{env_class}\.step\(\) before reset\(\): call reset\(\) first$"):
            step()
    finally:
        env.close()
