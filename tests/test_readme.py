"""Every fenced block of README.md is checked here, as written: users copy them.

- ```python blocks are executed, each in a fresh namespace with a temporary working directory; the
  blocks this file knows get extra checks of what their comments promise (``PYTHON_CHECKS``).
- ```yaml blocks are whole scenario files: written to a file, read by the scenario reader and
  validator (``smarts.scenario.load_scenario``), built into a ``DrivingParallelEnv`` and stepped;
  what each one is there to show is checked too (``YAML_CHECKS``).
- ```bash blocks are split into commands (a line, ``\\`` continuations joined, ``&&`` separating
  commands, ``#`` comments dropped) and every command must be listed in ``COMMANDS`` with how it is
  checked: ``run`` (for real, with a tiny budget), ``parse`` (too long to run here: minutes to
  hours of training or benchmarking; the real ``python -m train`` parser parses it and the training
  config or benchmark suite it names is loaded and validated, so every flag and value exists),
  ``ci`` (the test command: ``.ci/run`` runs exactly it) or ``not run`` with the reason.
- The one plain ``` block is the tour of the source tree: every folder it names exists and every
  package under ``smarts/`` is in it.

A block in another language, a bash command not in ``COMMANDS`` or an entry of ``COMMANDS`` that the
README no longer has fails ``test_every_block_is_checked``: nothing is skipped silently.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", re.S | re.M)


def _blocks() -> list[tuple[str, str, int]]:
    """(language, text, line of the opening fence) of every fenced block."""
    return [(m.group(1).strip(), m.group(2), README.count("\n", 0, m.start()) + 1) for m in FENCE.finditer(README)]


def _of(language: str) -> list[tuple[str, int]]:
    return [(text, line) for lang, text, line in _blocks() if lang == language]


def _commands(block: str) -> list[str]:
    """A bash block's commands: continuations joined, comments dropped, ``&&`` splitting."""
    commands = []
    for line in block.replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        command: list[str] = []
        for word in [*words, "&&"]:
            if word == "&&":
                if command:
                    commands.append(shlex.join(command))
                command = []
            else:
                command.append(word)
    return commands


# -------------------------------------------------------------------------------- bash commands
NOT_RUN = "not run"
PARSE = "parse"
RUN = "run"
CI = "ci"
COMMANDS: dict[str, tuple[str, str]] = {
    "pip install -e .": (NOT_RUN, "installs the package; these tests run in the installed checkout"),
    'pip install -e ".[test]"': (NOT_RUN, "installs the package with its test extra, as .ci/run does"),
    "python -m pytest -q -n auto": (CI, "the whole suite, this file included; .ci/run runs exactly this"),
    "python -m train ppo --task platoon": (PARSE, "300k training steps, 2-7 minutes"),
    "python -m train ppo --config platoon-two-cores --total-steps 6000000": (
        PARSE,
        "the main job: 6M training steps, 2-6 minutes",
    ),
    "python -m train ppo --task drive": (PARSE, "a full PPO training run"),
    "python -m train ppo --config configs/train/platoon-batched.yaml": (PARSE, "9.6M training steps, about 13 minutes"),
    "python -m train ppo --config configs/train/platoon-two-cores.yaml": (
        PARSE,
        "18M training steps, about 12 minutes",
    ),
    "python -m train ppo --task platoon --action-space continuous --init-from "
    "runs/train/platoon/latest/best.pt --runs-dir runs/train/platoon-c": (
        PARSE,
        "fine-tunes a trained checkpoint that only a finished run has",
    ),
    "python -m train ppo --task drive --lib sb3": (PARSE, "a full SB3 training run"),
    "python -m train ppo --task platoon --backend batched --envs 256 --frames-per-batch 16384 --minibatch-size 4096 --epochs 4": (
        PARSE,
        "a full training run on the batched backend; tests/batched/test_batched_training.py runs a short one",
    ),
    "python -m smarts.diagnostic --batched --batches none --sensor-batch 64 --sensor-breakdown": (
        NOT_RUN,
        "about 15 s of timing; tests/batched/test_batched_diagnostic.py runs it on a tiny budget",
    ),
    "python -m smarts.diagnostic --batched --ppo-steps 98304": (
        NOT_RUN,
        "minutes of timing up to B = 1,024 and two PPO runs; tests/batched/test_batched_diagnostic.py runs it on a tiny budget",
    ),
    "python -m smarts.diagnostic --batched --batches none --sensor-batch 0 --ppo-steps 786432 --ppo-envs 256,512,512 "
    "--ppo-frames 16384,32768,32768 --ppo-minibatch 4096,2048,2048 --ppo-epochs 4,1,1 --ppo-workers 1,1,2 "
    "--ppo-lr 0.0001,0.0003,0.0003 --ppo-rounds 3": (
        NOT_RUN,
        "nine PPO runs of 786k steps, about 6 minutes; tests/batched/test_batched_diagnostic.py runs the PPO rows on a "
        "tiny budget",
    ),
    "python -m train eval --agent runs/train/platoon/latest/best.pt --suite adaptive": (
        PARSE,
        "needs a trained checkpoint; 11 scenarios x 3 episodes x 4 agents",
    ),
    "python -m train benchmark --suite collaborative --agent zoo:drive --workers 2": (
        PARSE,
        "14 scenarios x 3 episodes x 4 agents, minutes",
    ),
    "python -m train benchmark --suite collaborative --agent zoo:tf --agent zoo:vcr --agent zoo:aid --episodes 3 "
    "--workers 2": (PARSE, "14 scenarios x 3 episodes x 6 agents, minutes"),
    "python -m train trajectories": (
        NOT_RUN,
        "minutes of simulation; tests/planners/test_training.py runs it on a two-scenario suite",
    ),
    "python -m train aid-predictor": (
        NOT_RUN,
        "tens of minutes on 2 cores; tests/planners/test_training.py trains a few steps",
    ),
    "python -m train tf-bc": (NOT_RUN, "minutes; tests/planners/test_training.py runs it on a two-scenario suite"),
    "python -m train vcr-classifier": (
        NOT_RUN,
        "about 15 minutes; tests/planners/test_training.py runs it on a two-scenario suite",
    ),
    "python -m smarts.benchmark.metrics runs/benchmark/collaborative/latest/logs": (
        RUN,
        "on the logs of a one-scenario, one-episode collaborative benchmark of the reference agents",
    ),
    "python -m train benchmark --suite collaborative --ray-address local": (
        PARSE,
        "the whole suite on a private Ray instance, minutes",
    ),
    "ray start --head": (NOT_RUN, "starts a Ray cluster head on this machine, left running"),
    'python -m train ppo --task drive --interface "{neighbours: {extended: true}, occlusion: {enabled: true}, '
    'lidar: {rays: 32}, rasters: {size: 32, layers: [drivable, occupancy, occlusion]}, ahead: true}" --comms '
    '"{range: 60, latency: 1, message_size: 4, penetration: 0.5}"': (
        PARSE,
        "a full training run; tests/test_train_every_scenario.py runs one batch with every sensor and V2V",
    ),
    "ray start --head --port 6379": (NOT_RUN, "starts a Ray cluster head on this machine, left running"),
    "ray start --address HEAD_IP:6379": (NOT_RUN, "joins another machine's Ray cluster, left running"),
    "python -m train ppo --task platoon --envs 512 --workers 32 --frames-per-batch 65536 --ray-address HEAD_IP:6379": (
        PARSE,
        "needs a Ray cluster at HEAD_IP; a full training run",
    ),
    "python -m train eval --agent runs/train/platoon/latest/final.pt --suite adaptive --ray-address auto": (
        PARSE,
        "needs a trained checkpoint and the cluster started by `ray start --head`",
    ),
    "python -m train ppo --task platoon --envs 16 --workers 4 --ray-address HOST:6379": (
        PARSE,
        "needs a Ray cluster at HOST; a full training run",
    ),
    "python -m train benchmark --suite adaptive --agent zoo:keep-lane --episodes 1": (
        PARSE,
        "11 scenarios x 4 agents, minutes",
    ),
    "smarts viz runs/benchmark/adaptive/latest/logs": (
        NOT_RUN,
        "serves until Ctrl-C; tests/viz/test_server.py and test_browser.py serve such a folder",
    ),
    "python -m train enjoy --agent zoo:platoon-rtp --scenario adaptive:a08_lead_turns_left_at_junction --viz": (
        NOT_RUN,
        "waits for a browser; tests/viz/test_browser.py streams a live env into chromium",
    ),
    "python -m train enjoy --agent zoo:keep-lane --scenario adaptive:a08_lead_turns_left_at_junction --video drive.mp4": (
        NOT_RUN,
        "tests/viz/test_enjoy.py runs it on a01 with --max-steps 40 and reads the video back",
    ),
    "smarts replay info trajectories.csv --format ngsim --json": (
        NOT_RUN,
        "needs the user's NGSIM file; tests/replay/test_replay_cli.py runs it on a CSV it writes",
    ),
    "smarts replay show trajectories.csv --format ngsim --swap-xy --flip-y --map road.net.xml --out replay.mp4": (
        NOT_RUN,
        "needs the user's files; tests/replay/test_replay_cli.py renders a CSV it writes to .png, .gif and .mp4",
    ),
}


def _readme_commands() -> list[str]:
    return [command for block, _ in _of("bash") for command in _commands(block)]


def _listed(command: str) -> str | None:
    """The key of ``COMMANDS`` that is ``command`` (compared word by word, as the shell splits)."""
    return next((key for key in COMMANDS if shlex.split(key) == shlex.split(command)), None)


def test_every_block_is_checked():
    languages = {lang for lang, _, _ in _blocks()}
    assert languages <= {"python", "yaml", "bash", ""}, f"no check for README blocks in {languages}"
    assert len(_of("")) == 1, "the tour is the only plain block"
    commands = _readme_commands()
    unlisted = [c for c in commands if _listed(c) is None]
    assert not unlisted, f"README commands with no check: add them to COMMANDS: {unlisted}"
    stale = sorted(set(COMMANDS) - {_listed(c) for c in commands})
    assert not stale, f"COMMANDS lists commands the README no longer has: {stale}"


def test_ci_runs_the_readme_test_command():
    test_command = next(b.strip() for b, _ in _of("bash") if "pytest" in b)
    assert test_command in (ROOT / ".ci" / "run").read_text()
    assert [c for c, (how, _) in COMMANDS.items() if how == CI] == ["python -m pytest -q -n auto"]


def _train_argv(command: str) -> list[str]:
    words = shlex.split(command)
    assert words[:3] == ["python", "-m", "train"], command
    return words[3:]


@pytest.mark.parametrize("command", [c for c, (how, _) in COMMANDS.items() if how == PARSE])
def test_long_commands_parse_and_name_valid_settings(command):
    # Not run (see COMMANDS for why): parsed by the real parser, which exits on an unknown flag or
    # a bad value, then the config or suite they name is loaded and validated as the run would.
    from smarts.benchmark.suites import load_suite
    from train.__main__ import build_parser
    from train.config import TrainConfig, load_config

    argv = _train_argv(command)
    args = build_parser(argv).parse_args(argv)
    if args.command == "ppo":
        overrides = {n: getattr(args, n) for n in TrainConfig.model_fields if n != "task"}
        load_config(args.task, args.config, {k: v for k, v in overrides.items() if v is not None})
    else:
        assert args.command in ("benchmark", "eval")
        assert load_suite(args.suite).scenarios


def test_metrics_command_scores_a_benchmark_logs_folder(tmp_path, monkeypatch):
    # A real benchmark run in the layout of the README's (runs/benchmark/collaborative/001/logs/<agent>/
    # <scenario>/episode_000.npz, one folder per agent; latest -> 001), cut down to one short scenario
    # and episode.
    import yaml

    from train.__main__ import main as train_main

    suite = yaml.safe_load((ROOT / "configs" / "benchmark" / "collaborative.yaml").read_text())
    suite["episodes"] = 1
    suite["scenarios"] = [{**suite["scenarios"][0], "time_limit": 3}]
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(suite))
    monkeypatch.chdir(tmp_path)
    assert train_main(["benchmark", "--suite", "tiny.yaml", "--workers", "1", "--quiet"]) == 0
    logs = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*.npz"))
    assert len(logs) == 3 and len({p.name for p in logs}) == 1, logs

    (command,) = [c for c, (how, _) in COMMANDS.items() if how == RUN]
    words = shlex.split(command)
    done = subprocess.run([sys.executable, *words[1:]], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    for agent in ("zoo:keep-lane", "zoo:random", "zoo:stand-still"):
        assert f"agent: {agent}\ntask: collaborative\n" in done.stdout
    assert done.stdout.count("\noverall ") == 3


# ------------------------------------------------------------------------------ python blocks
def _check_intersection(namespace: dict, printed: list[str]) -> None:
    from smarts.core.vehicle_table import Role
    from smarts.sensors.topdown import ROLE_COLOURS

    assert printed == ["agent_0 ['reached_goal']", "agent_1 ['reached_goal']"]
    frame = namespace["frame"]
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    # The kept frame shows a vehicle still driving: pixels of an agent's colour.
    assert (frame == ROLE_COLOURS[int(Role.AGENT)]).all(axis=2).sum() > 20


def _check_gymnasium(namespace: dict, printed: list[str]) -> None:
    env = namespace["env"]
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


PYTHON_CHECKS = {
    'DrivingParallelEnv("intersection_4way_signal_right"': _check_intersection,
    'gymnasium.make("smarts/Driving-v0"': _check_gymnasium,
}


@pytest.mark.parametrize("block,line", _of("python"), ids=[f"line{n}" for _, n in _of("python")])
def test_python_block_runs(block, line, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__main__"}
    exec(compile(block, f"README.md block at line {line}", "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    checks = [check for key, check in PYTHON_CHECKS.items() if key in block]
    for check in checks:
        check(namespace, printed)


def test_every_python_check_has_its_block():
    blocks = [b for b, _ in _of("python")]
    for key in PYTHON_CHECKS:
        assert sum(key in b for b in blocks) == 1, key


# -------------------------------------------------------------------------------- yaml blocks
def _check_traffic(env, spec, obs) -> None:
    from smarts.core.vehicle_table import Role

    assert spec.traffic.engine == "sumo" and spec.traffic.pedestrians
    table = env.sim.table
    roles = {int(table.role[r]) for r in table.alive_rows}
    assert int(Role.TRAFFIC) in roles and int(Role.PEDESTRIAN) in roles


def _check_sensors(env, spec, obs) -> None:
    obs = obs["agent_0"]
    assert obs["rasters"].shape == (5, 64, 64) and obs["rgb"].shape == (64, 64, 3)
    assert obs["lidar"].shape == obs["lidar_hit"].shape == (64,)
    assert obs["neighbours"].shape[0] == 8


def _check_comms(env, spec, obs) -> None:
    assert env.action_space("agent_0").shape == (3 + 8,)
    assert obs["agent_0"]["messages"].shape == (8, 6 + 8)
    assert spec.comms.agent_channels == {"agent_1": 1}


def _check_scenario(env, spec, obs) -> None:
    assert spec.name == "my_left_turn" and spec.vehicle_capacity == 256
    assert env.possible_agents == ["agent_0"]


def _check_replay(env, spec, obs) -> None:
    replay = next(p for p in env.sim.providers if p.name == "replay")
    assert spec.replay.take_over == {"ego": "12"} and env.possible_agents == ["ego"]
    assert (replay.state > 0).sum() >= 3  # the recorded vehicles came in (the ego's was taken over)
    assert replay.handed_over == ["replay-13"]  # came up behind the standing ego: turned reactive


def _replay_files(folder: Path) -> None:
    """The NGSIM CSV and map the README's replay block names: vehicle 12 (taken over) ahead of 13 in
    one lane, 14 ahead of them in the other, on the built-in straight two-lane road."""
    import shutil

    from smarts.scenario.builtin_maps import builtin_map_path
    from tests.replay.files import LANE0_Y, LANE1_Y, straight, write_ngsim

    shutil.copy(builtin_map_path("straight_2lane"), folder / "road.net.xml")
    write_ngsim(folder / "trajectories.csv", {
        "12": straight(500, 150, 60.0, 10.0, LANE0_Y),
        "13": straight(500, 150, 30.0, 10.0, LANE0_Y),
        "14": straight(520, 100, 100.0, 12.0, LANE1_Y),
    })  # fmt: skip


YAML_FILES = {"replay:": _replay_files}
"""Files a yaml block names, written next to it before it is read."""

YAML_CHECKS = {
    "name: my_left_turn": _check_scenario,
    "traffic:\n  engine: sumo": _check_traffic,
    "    interface:": _check_sensors,
    "comms:": _check_comms,
    "replay:": _check_replay,
}


@pytest.mark.parametrize("block,line", _of("yaml"), ids=[f"line{n}" for _, n in _of("yaml")])
def test_yaml_block_is_a_scenario_that_runs(block, line, tmp_path):
    from smarts.env import DrivingParallelEnv
    from smarts.scenario import load_scenario

    path = tmp_path / f"readme_line{line}.yaml"
    path.write_text(block)
    for key, write in YAML_FILES.items():
        if key in block:
            write(tmp_path)
    spec = load_scenario(path)
    env = DrivingParallelEnv(str(path))
    try:
        last, _ = env.reset(seed=0)
        # 20 s with every agent holding still (a zero action of its space): traffic and pedestrians
        # come in around them.
        for _ in range(200):
            if not env.agents:
                break
            actions = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents}
            obs, *_ = env.step(actions)
            for agent, o in obs.items():
                assert env.observation_space(agent).contains(o), agent
            last.update(obs)  # each agent's latest observation
        checks = [check for key, check in YAML_CHECKS.items() if key in block]
        assert checks, f"README yaml block at line {line}: add what it shows to YAML_CHECKS"
        for check in checks:
            check(env, spec, last)
    finally:
        env.close()


def test_every_yaml_check_has_its_block():
    blocks = [b for b, _ in _of("yaml")]
    for key in YAML_CHECKS:
        assert sum(key in b for b in blocks) == 1, key


# ------------------------------------------------------------------------------- the tour
def test_tour_names_the_source_tree():
    (tour,) = [b for b, _ in _of("")]
    top = re.findall(r"^([a-z_]+)/ ", tour, flags=re.M)
    packages = re.findall(r"^  ([a-z_]+)/ ", tour, flags=re.M)
    assert top and packages
    for name in top:
        assert (ROOT / name).is_dir(), name
    assert top[0] == "smarts"
    on_disk = sorted(p.parent.name for p in (ROOT / "smarts").glob("*/__init__.py"))
    assert sorted(packages) == on_disk
