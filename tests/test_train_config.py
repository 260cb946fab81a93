"""The training config schema: YAML and command-line overrides validated by one model."""

import dataclasses
import json

import pytest

from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.env.task_rewards import RewardWeights
from train.__main__ import build_parser, main
from train.config import ConfigError, LaneRelativeSection, RewardSection, TrainConfig, load_config


def test_a_bad_yaml_names_the_file_and_every_field_with_a_did_you_mean(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("task: drive\nscenarios: [collaborative:*]\ntotal_step: 100\ngamma: 2\n"
                    "reward: {progres: 1}\nlane_relative: {threshold: 1.5}\nhidden: [64, 0]\n")  # fmt: skip
    with pytest.raises(ConfigError) as caught:
        load_config(path=path)
    lines = str(caught.value).splitlines()
    assert all(line.startswith(f"{path}: ") for line in lines) and len(lines) == 5  # all at once
    text = str(caught.value)
    assert "total_step: unknown field; did you mean 'total_steps'?" in text
    assert "reward.progres: unknown field; did you mean 'progress'?" in text
    assert "gamma: expected a number in (0, 1], got 2" in text
    assert "lane_relative.threshold: expected a number in (0, 1), got 1.5" in text
    assert "hidden: expected a list of positive layer sizes" in text
    path.write_text("- not a mapping\n")
    with pytest.raises(ConfigError, match="mine.yaml: expected a mapping"):
        load_config(path=path)


def test_a_bad_override_names_the_flag_and_the_field(tmp_path, capsys):
    args = ["ppo", "--task", "drive", "--envs", "0", "--reward", "{gaol: 1}", "--hidden", "64,x", "--obs-norm", "maybe",
            "--out-dir", str(tmp_path / "run")]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--envs: envs: expected a positive integer, got 0" in err
    assert "--reward: reward.gaol: unknown field; did you mean 'goal'?" in err
    assert "--hidden: hidden[1]: input should be a valid integer, got 'x'" in err and "--obs-norm: obs_norm: " in err
    assert not (tmp_path / "run").exists()
    with pytest.raises(ConfigError, match="--workers: workers: must be <= envs \\(2\\)"):
        load_config("platoon", overrides={"envs": "2", "workers": "3"})
    with pytest.raises(ConfigError, match="--interface: interface: leed: unknown field; did you mean 'lead'"):
        load_config("platoon", overrides={"interface": "{leed: true}"})


def test_help_lists_every_field_with_the_task_defaults(capsys):
    for task, steps in (("platoon", 300000), ("drive", 60000)):
        with pytest.raises(SystemExit):
            main(["ppo", "--task", task, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert f"(int; default: {steps} in {task}.yaml)" in text
        assert "--out-dir OUT_DIR, --out OUT_DIR" in text and f"'runs/train/{task}' in {task}.yaml" in text
        assert "(float; default: 0.5)" in text  # max_grad_norm: not in the YAML, the schema's default
        for name in TrainConfig.model_fields:
            assert "--" + name.replace("_", "-") in text or name == "out"


def test_overrides_of_lists_and_sections_parse_as_yaml():
    cfg = load_config("platoon", overrides={"hidden": "256,256", "init_log_std": "[-1, -0.5]", "obs_norm": "no",
                                            "reward": "{follow: 2}", "lane_relative": "{max_jerk: 1.5}",
                                            "interface": "{lead: true}", "eval_suite": "null", "lr": "1e-4",
                                            "scenarios": "adaptive:a01_straight_free, adaptive:a02_straight_traffic"})  # fmt: skip
    assert cfg.hidden == [256, 256] and cfg.init_log_std == [-1.0, -0.5] and cfg.obs_norm is False
    assert cfg.lr == 1e-4 and cfg.eval_suite is None
    assert cfg.scenarios == ["adaptive:a01_straight_free", "adaptive:a02_straight_traffic"]
    assert cfg.reward.model_dump() == {"follow": 2.0}  # a section records what it was given...
    assert cfg.reward_weights().follow == 2.0 and cfg.reward_weights().task == "platoon"  # ...the rest default
    assert cfg.lane_relative_params().max_jerk == 1.5 and not cfg.observation_interface().ahead
    assert load_config("platoon", overrides={"hidden": "[256, 256]"}).hidden == [256, 256]
    # --out-dir and its alias --out are the config's out, the one place the run folder comes from
    for option in ("--out-dir", "--out"):
        assert build_parser().parse_args(["ppo", option, "elsewhere"]).out == "elsewhere"


def test_config_json_round_trips_to_an_equal_config(tmp_path):
    cfg = load_config("drive", overrides={"hidden": "64", "reward": "{goal: 5, task: drive}", "init_from": "x.pt"})
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg.model_dump(), indent=2))
    again = load_config(path=path)
    assert again == cfg and again.model_dump() == cfg.model_dump()
    assert json.loads(path.read_text())["reward"] == {"goal": 5.0, "task": "drive"}
    assert json.loads(path.read_text())["hidden"] == [64]  # lists, as the resume checks compare


def test_sections_have_the_fields_and_defaults_of_the_settings_they_build():
    for section, settings in ((RewardSection, RewardWeights), (LaneRelativeSection, LaneRelativeParams)):
        own = {f.name: f.default for f in dataclasses.fields(settings)}
        assert set(section.model_fields) == set(own)
        for name, info in section.model_fields.items():
            assert name == "task" or info.default == own[name], name


def test_device_and_sim_device_name_where_the_learner_and_the_torch_stages_run(tmp_path, capsys):
    import torch

    assert load_config("platoon").device == load_config("platoon").sim_device == "cpu"
    assert load_config("platoon", overrides={"sim_device": "torch-cpu"}).sim_device == "torch-cpu"
    with pytest.raises(ConfigError, match=r"--sim-device: sim_device: unknown device 'gpu'"):
        load_config("platoon", overrides={"sim_device": "gpu"})
    cfg = load_config("platoon", overrides={"backend": "batched", "device": "torch-cpu"})
    assert cfg.device == "torch-cpu"
    # A config naming a GPU stays readable without one (a run's config.json on another machine)...
    cfg = load_config("platoon", overrides={"backend": "batched", "device": "cuda:1"})
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg.model_dump()))
    assert load_config(path=path).device == "cuda:1"
    with pytest.raises(
        ConfigError, match=r"--device: device: unknown device 'gpu'; expected one of cpu, torch-cpu, cuda, cuda:N"
    ):
        load_config("platoon", overrides={"backend": "batched", "device": "gpu"})
    for device in ("cuda", "torch-cpu"):  # both backends build the one batched env, with its torch stages
        assert load_config("platoon", overrides={"backend": "per_env", "device": device}).device == device
    # ...but training refuses it, before any run folder is made, where torch sees no GPU.
    if not torch.cuda.is_available():
        out = tmp_path / "run"
        assert (
            main(["ppo", "--task", "platoon", "--backend", "batched", "--device", "cuda", "--out-dir", str(out)]) == 2
        )
        assert "device: 'cuda' asks for a GPU but no CUDA GPU is visible" in capsys.readouterr().err
        assert not out.exists()
        for lib in ("torchrl", "sb3"):
            args = ["ppo", "--task", "platoon", "--lib", lib, "--sim-device", "cuda", "--out-dir", str(out)]
            assert main(args) == 2 and not out.exists()


def test_both_trainers_hand_the_sim_device_to_the_batched_backend():
    """``sim_device`` places the simulation's torch stages (``device`` is the learner's)."""
    import torch

    from smarts.dynamics.agent_provider import AgentProvider
    from train.ppo import make_driving, make_env
    from train.sb3_ppo import make_vec_env

    def agent_device(driving):
        return {p.device for group in driving.groups for p in group.sim.providers if isinstance(p, AgentProvider)}

    for backend, device, expected in (("batched", "torch-cpu", torch.device("cpu")), ("per_env", "torch-cpu", torch.device("cpu")),
                                      ("batched", "cpu", None)):  # fmt: skip
        cfg = load_config("platoon", overrides={"backend": backend, "sim_device": device, "device": "torch-cpu",
                                                "envs": "2", "workers": "0"})  # fmt: skip
        driving = make_driving(cfg)
        try:
            assert agent_device(driving) == {expected}
        finally:
            driving.close()
        env = make_env(cfg)
        try:
            assert agent_device(env.base_env.driving) == {expected}
        finally:
            env.close()
        vec = make_vec_env(cfg.model_copy(update={"lib": "sb3"}))
        try:
            assert agent_device(vec.driving) == {expected}
        finally:
            vec.close()


def test_an_eval_video_scenario_the_suite_lacks_is_refused_before_the_run():
    assert load_config("platoon", overrides={"eval_video_scenario": "a09_lead_turns_right_at_signal_medium"})
    with pytest.raises(ConfigError, match="eval_video_scenario: suite 'adaptive' has no scenario 'a99'; it has a01_"):
        load_config("platoon", overrides={"eval_video_scenario": "a99"})


def test_config_takes_a_shipped_recipe_by_name_from_anywhere(tmp_path, monkeypatch, capsys):
    """``--config platoon-two-cores`` (the main job's) is the shipped YAML, in a checkout or from a
    wheel; a file of that name in the working folder comes first; an unknown name lists the shipped."""
    from train.config import CONFIG_DIR, ConfigError

    monkeypatch.chdir(tmp_path)
    by_name = load_config(None, "platoon-two-cores")
    assert by_name == load_config(None, CONFIG_DIR / "platoon-two-cores.yaml")
    assert by_name.backend == "batched" and by_name.workers == 2
    shipped = (CONFIG_DIR / "platoon-two-cores.yaml").read_text()
    (tmp_path / "platoon-two-cores").write_text(shipped.replace("total_steps: 18000000", "total_steps: 512"))
    assert load_config(None, "platoon-two-cores").total_steps == 512
    with pytest.raises(ConfigError, match=r"--config platoon-nope: no such file.*platoon-batched, platoon-two-cores"):
        load_config(None, "platoon-nope")
    assert main(["ppo", "--config", "platoon-nope", "--out-dir", str(tmp_path / "out")]) == 2
    assert "no shipped training config of that name" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
