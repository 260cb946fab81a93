"""`python -m train ppo` end to end with tiny settings: TensorBoard events, checkpoints, eval."""

import json

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from agents.ppo import PPOPolicy
from train.__main__ import main


def test_ppo_trains_writes_tensorboard_and_a_loadable_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["ppo", "--task", "platoon", "--total-steps", "256", "--frames-per-batch", "128", "--minibatch-size", "64",
            "--epochs", "1", "--envs", "1", "--eval-episodes", "0", "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    events = list((out / "tensorboard").glob("events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 0
    blob = torch.load(out / "final.pt", weights_only=True)
    assert blob["step"] == 256 and blob["config"]["task"] == "platoon"
    assert "loss/objective" in blob["metrics"] and "optimizer" in blob
    policy = PPOPolicy.load(out / "final.pt")
    assert policy.action_space == "relative_target_pose"
    assert json.loads((out / "config.json").read_text())["total_steps"] == 256
    assert "checkpoint:" in capsys.readouterr().out


def test_bad_training_settings_name_the_field(tmp_path, capsys):
    assert main(["ppo", "--task", "platoon", "--lr", "-1", "--out-dir", str(tmp_path)]) == 2
    assert "lr: expected a positive number" in capsys.readouterr().err
    assert main(["ppo", "--task", "flying", "--out-dir", str(tmp_path)]) == 2
    assert "unknown task 'flying'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["ppo", "--no-such-flag", "1"])


def test_sb3_training_exports_a_checkpoint_the_benchmark_can_load(tmp_path):
    from agents.loader import load_policy_file
    from smarts.benchmark.agents import policy_setup

    out = tmp_path / "sb3"
    args = ["ppo", "--task", "platoon", "--lib", "sb3", "--total-steps", "128", "--envs", "2", "--frames-per-batch",
            "64", "--minibatch-size", "32", "--epochs", "1", "--eval-episodes", "0", "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    assert list((out / "tensorboard").rglob("events.out.tfevents.*"))
    policy = load_policy_file(out / "final.pt")  # weights_only load of the exported SB3 policy
    assert (policy.action_space, policy.controller) == ("relative_target_pose", "lane_relative")
    setup = policy_setup(policy, str(out / "final.pt"))  # the recorded interface, validated
    assert setup.interface is not None and setup.interface.lead
    from smarts.env import DrivingParallelEnv
    from train.run import training_spec

    env = DrivingParallelEnv(training_spec("adaptive:a01_straight_free", "rtp", "lane_relative"),
                             observation=setup.interface, lane_relative=setup.lane_relative)  # fmt: skip
    obs, _ = env.reset(seed=0)
    action = policy.act({k: v[None] for k, v in obs["agent_0"].items()})
    assert action.shape == (1, 2) and env.action_space("agent_0").contains(action[0].astype("float32"))


def test_resume_continues_from_the_checkpoint_step(tmp_path):
    out = tmp_path / "run"
    base = ["ppo", "--task", "platoon", "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1",
            "--envs", "2", "--scenarios", "adaptive:a01_straight_free", "--eval-episodes", "0", "--out-dir", str(out),
            "--quiet"]  # fmt: skip
    assert main([*base, "--total-steps", "128"]) == 0
    first = torch.load(out / "final.pt", weights_only=True)
    assert main([*base, "--total-steps", "256", "--resume", str(out / "final.pt")]) == 0
    second = torch.load(out / "final.pt", weights_only=True)
    assert first["step"] == 128 and second["step"] == 256
    assert not torch.equal(first["actor"]["net.0.weight"], second["actor"]["net.0.weight"])
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"junk")
    assert main([*base, "--total-steps", "256", "--resume", str(bad)]) == 2


@pytest.mark.parametrize(
    "flags, what",
    [
        (["--controller", "direct"], "controller"),
        (["--interface", "{lead: false}"], "observation interface"),
        (["--hidden", "32,32"], "hidden layers"),
    ],
)
def test_resume_refuses_a_checkpoint_of_another_setup_before_touching_the_run(tmp_path, capsys, flags, what):
    first = tmp_path / "first"
    base = ["ppo", "--task", "platoon", "--frames-per-batch", "64", "--minibatch-size", "64", "--epochs", "1",
            "--envs", "1", "--total-steps", "64", "--eval-episodes", "0", "--quiet"]  # fmt: skip
    assert main([*base, "--out-dir", str(first)]) == 0
    second = tmp_path / "second"
    args = [*base, "--total-steps", "128", "--out-dir", str(second), "--resume", str(first / "final.pt"), *flags]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"trained with {what}" in err and "final.pt" in err
    assert not second.exists()  # refused before the run folder (or any env) was made


def test_training_config_takes_every_suite_scenario_and_the_task_reward():
    from train.config import load_config
    from train.run import scenario_names

    cfg = load_config("platoon")
    names = scenario_names(cfg.scenarios)
    assert len(names) == 11 and names[0] == "adaptive:a01_straight_free"
    assert cfg.controller == "lane_relative" and cfg.observation_interface().lead
    assert cfg.reward_weights().task == "platoon"
    assert load_config("drive").reward_weights().task == "drive"
    from train.config import ConfigError

    with pytest.raises(ConfigError, match="--reward: reward.speed_bonus: unknown field; did you mean 'speeding'"):
        load_config("platoon", overrides={"reward": "{speed_bonus: 1}"})


def test_the_ray_modules_normalise_with_the_statistics_the_learner_updates():
    """The TorchRL modules a Ray collector acts with hold references to the learner's buffers: the
    observation statistics must be updated in place, or the collectors would act on stale inputs."""
    from train.config import load_config
    from train.ppo import collection_modules, env_parts, make_env

    cfg = load_config("platoon", overrides={"envs": 1, "workers": 0})
    env = make_env(cfg)
    try:
        parts = env_parts(env, cfg)
        actor = collection_modules(parts, env.action_spec)
        parts.normalizer.update(torch.randn(64, parts.layout.size) * 3.0 + 1.0)
        for name, buffer in actor.named_buffers():
            if name.endswith(("normalizer.mean", "normalizer.var", "normalizer.count")):
                own = getattr(parts.normalizer, name.rsplit(".", 1)[1])
                assert torch.equal(buffer, own), name
    finally:
        env.close()


def test_periodic_evaluation_selects_best_by_s_bench_and_logs_it(tmp_path):
    from pathlib import Path

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    suite = Path(__file__).parent / "benchmark" / "tiny_suite.yaml"
    out = tmp_path / "run"
    args = ["ppo", "--task", "drive", "--scenarios", "collaborative:c01_4way_1lane_left_free", "--total-steps", "256",
            "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1", "--envs", "1", "--eval-every", "128",
            "--eval-episodes", "1", "--eval-suite", str(suite), "--eval-workers", "1", "--out-dir", str(out),
            "--eval-video-scenario", "t2_straight_traffic", "--quiet"]  # fmt: skip
    assert main(args) == 0
    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"scalars": 0, "images": 0})
    acc.Reload()
    s_bench = {e.step: e.value for e in acc.Scalars("eval/S_bench")}
    assert set(s_bench) == {128, 256}  # every eval_every steps; the one at the end is the final evaluation
    assert all(0.0 <= v <= 1.0 for v in s_bench.values())
    assert "eval/PR" in acc.Tags()["scalars"] and "eval/MTE" in acc.Tags()["scalars"]
    assert any(t.startswith("eval_trajectories/") for t in acc.Tags()["images"])
    # An evaluation video of the chosen scenario at every evaluation: an animated GIF.
    assert not any(t.startswith("eval_video/t1_left") for t in acc.Tags()["images"])
    videos = acc.Images("eval_video/t2_straight_traffic")
    assert [v.step for v in videos] == [128, 256]
    from io import BytesIO

    from PIL import Image

    gif = Image.open(BytesIO(videos[0].encoded_image_string))
    assert gif.format == "GIF" and gif.n_frames > 10
    best = torch.load(out / "best.pt", weights_only=True)
    assert s_bench[best["step"]] == max(s_bench.values())
    assert len(acc.Scalars("eval/S_bench")) == 2
    report = (out / "evals" / "step_128" / "report.md").read_text()
    assert "zoo:stand-still (reference)" in report and "seed 3000" in report
    # The selected checkpoint goes through `train eval` like any agent.
    assert main(["eval", "--agent", str(out / "best.pt"), "--suite", str(suite), "--episodes", "1",
                 "--workers", "1", "--out", str(tmp_path / "eval"), "--quiet"]) == 0  # fmt: skip
    assert (tmp_path / "eval" / "results.json").is_file()
    # Resuming from best.pt continues the run from that checkpoint's step to a longer budget.
    assert main([*args[:-3], "--total-steps", "384", "--eval-episodes", "0", "--out-dir", str(out), "--quiet",
                 "--resume", str(out / "best.pt")]) == 0  # fmt: skip
    assert torch.load(out / "final.pt", weights_only=True)["step"] == 384


def test_periodic_evaluation_does_not_change_the_training_run(tmp_path):
    from pathlib import Path

    suite = Path(__file__).parent / "benchmark" / "tiny_suite.yaml"
    base = ["ppo", "--task", "drive", "--scenarios", "collaborative:c01_4way_1lane_left_free", "--total-steps", "384",
            "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1", "--envs", "1",
            "--eval-suite", str(suite), "--quiet"]  # fmt: skip
    assert main(base + ["--eval-every", "128", "--eval-episodes", "1", "--out-dir", str(tmp_path / "a")]) == 0
    assert main(base + ["--eval-episodes", "0", "--out-dir", str(tmp_path / "b")]) == 0
    with_eval = torch.load(tmp_path / "a" / "final.pt", weights_only=True)
    without = torch.load(tmp_path / "b" / "final.pt", weights_only=True)
    assert with_eval["step"] == without["step"] == 384
    for name, tensor in without["actor"].items():
        assert torch.equal(with_eval["actor"][name], tensor), name


def test_init_from_starts_a_new_run_from_trained_networks_in_another_action_space(tmp_path, capsys):
    base = ["ppo", "--task", "platoon", "--scenarios", "adaptive:a01_straight_free", "--frames-per-batch", "64",
            "--minibatch-size", "64", "--epochs", "1", "--envs", "1", "--total-steps", "64", "--eval-episodes", "0",
            "--quiet"]  # fmt: skip
    assert main([*base, "--out-dir", str(tmp_path / "rtp")]) == 0
    source = torch.load(tmp_path / "rtp" / "final.pt", weights_only=True)
    assert main([*base, "--action-space", "continuous", "--init-from", str(tmp_path / "rtp" / "final.pt"),
                 "--out-dir", str(tmp_path / "c")]) == 0  # fmt: skip
    tuned = torch.load(tmp_path / "c" / "final.pt", weights_only=True)
    assert tuned["action"]["space"] == "continuous" and tuned["step"] == 64  # a new run, from step 0
    assert not torch.equal(tuned["actor"]["net.0.weight"], source["actor"]["net.0.weight"])  # trained on
    torch.testing.assert_close(tuned["normalizer"]["count"], source["normalizer"]["count"] + 64)
    # Another observation is refused before anything is built.
    assert main([*base, "--interface", "{lead: true}", "--init-from", str(tmp_path / "rtp" / "final.pt"),
                 "--out-dir", str(tmp_path / "x")]) == 2  # fmt: skip
    assert "trained with observation interface" in capsys.readouterr().err and not (tmp_path / "x").exists()


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_total_steps_is_honoured_within_one_step_of_every_slot_on_both_libraries(tmp_path, lib):
    """3 slots (a01: one follower, a02: two), batches of 64 frames (22 steps of every slot) and a
    budget of 100: two batches, the second only what is still needed: 102 steps (34 of every
    slot), the same with either library; no library warns about the last, smaller batch."""
    import warnings

    args = ["ppo", "--task", "platoon", "--lib", lib, "--scenarios",
            "adaptive:a01_straight_free,adaptive:a02_straight_two_followers_low", "--total-steps", "100",
            "--frames-per-batch", "64", "--minibatch-size", "32", "--epochs", "1", "--envs", "2",
            "--eval-episodes", "0", "--out-dir", str(tmp_path / "run"), "--quiet"]  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(args) == 0
    assert not [w for w in caught if "divisible" in str(w.message) or "mini-batch size" in str(w.message)]
    assert torch.load(tmp_path / "run" / "final.pt", weights_only=True)["step"] == 102


def test_ctrl_c_saves_interrupted_pt_and_exits_130_without_a_traceback(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    command = [sys.executable, "-m", "train", "ppo", "--task", "platoon", "--scenarios", "adaptive:a01_straight_free",
               "--total-steps", "1000000", "--frames-per-batch", "64", "--minibatch-size", "64", "--epochs", "1",
               "--envs", "1", "--eval-episodes", "0", "--out-dir", str(out), "--quiet"]  # fmt: skip
    # SIGINT as from a terminal, even when the tests run in the background (where it is ignored).
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONWARNINGS": "ignore"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    deadline = time.monotonic() + 180
    while not (out / "last.pt").is_file() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.5)
    assert (out / "last.pt").is_file(), proc.stderr.read() if proc.poll() is not None else "no batch in 180 s"
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr
    assert (out / "interrupted.pt").is_file() and "checkpoint saved to" in stdout


def test_the_final_evaluation_shows_progress_unless_quiet(tmp_path, capsys):
    from pathlib import Path

    suite = Path(__file__).parent / "benchmark" / "tiny_suite.yaml"
    base = ["ppo", "--task", "drive", "--scenarios", "collaborative:c01_4way_1lane_left_free", "--total-steps", "128",
            "--frames-per-batch", "128", "--minibatch-size", "64", "--epochs", "1", "--envs", "1",
            "--eval-episodes", "1", "--eval-suite", str(suite), "--eval-workers", "1"]  # fmt: skip
    assert main(base + ["--out-dir", str(tmp_path / "a")]) == 0
    assert "episodes" in capsys.readouterr().out  # the evaluation's own bar after training's
    assert main(base + ["--out-dir", str(tmp_path / "b"), "--quiet"]) == 0
    assert "episodes" not in capsys.readouterr().out


def test_every_run_gets_its_own_numbered_folder_and_latest_points_to_the_newest(tmp_path):
    base = ["ppo", "--task", "platoon", "--scenarios", "adaptive:a01_straight_free", "--total-steps", "64",
            "--frames-per-batch", "64", "--minibatch-size", "64", "--epochs", "1", "--envs", "1",
            "--eval-episodes", "0", "--runs-dir", str(tmp_path), "--quiet"]  # fmt: skip
    assert main(base) == 0
    first = torch.load(tmp_path / "001" / "final.pt", weights_only=True)
    assert main(base) == 0  # the same command again: a new folder, the first run untouched
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.isdigit()) == ["001", "002"]
    assert (tmp_path / "latest").resolve() == (tmp_path / "002").resolve()
    again = torch.load(tmp_path / "001" / "final.pt", weights_only=True)
    assert all(torch.equal(first["actor"][k], again["actor"][k]) for k in first["actor"])
    # --resume without --out-dir continues in the checkpoint's own folder
    assert main([*base[:6], "128", *base[7:], "--resume", str(tmp_path / "001" / "last.pt")]) == 0
    assert torch.load(tmp_path / "001" / "final.pt", weights_only=True)["step"] == 128
    assert not (tmp_path / "003").exists()
    import json

    assert json.loads((tmp_path / "002" / "config.json").read_text())["out"] == str(tmp_path / "002")


def test_the_ppo_settings_reach_torchrl_objects():
    from train.config import load_config
    from train.ppo import Learner, driving_parts, make_driving

    cfg = load_config("platoon", overrides={"envs": 1, "scenarios": "adaptive:a01_straight_free", "gamma": 0.9,
                                            "gae_lambda": 0.8, "clip_epsilon": 0.3, "entropy_coeff": 0.02,
                                            "critic_coeff": 0.7, "lr": 3e-4, "minibatch_size": 32, "workers": 0,
                                            "hidden": [32, 16]})  # fmt: skip
    driving = make_driving(cfg)
    try:
        parts = driving_parts(driving, cfg)
    finally:
        driving.close()
    learner = Learner(cfg, parts, torch.device("cpu"))
    loss = learner.loss
    assert float(loss.clip_epsilon) == pytest.approx(0.3) and float(loss.entropy_coeff) == pytest.approx(0.02)
    assert float(loss.critic_coeff) == pytest.approx(0.7) and learner.optimizer.param_groups[0]["lr"] == 3e-4
    rows = torch.arange(100)
    sizes = [len(b) for b in learner.minibatches(rows, {"x": torch.arange(100.0)})]
    assert sizes == [32, 32, 32, 4]
    seen = torch.cat([b["x"] for b in learner.minibatches(rows, {"x": torch.arange(100.0)})])
    assert sorted(seen.tolist()) == list(range(100))  # every step once
    linears = [m for m in parts.actor_net.net if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linears] == [32, 16, 2]  # torchrl's MLP with the config's layers
    # GAE with the configured discount and lambda: one slot's 3 steps, no episode end, the last
    # step's next observation its own
    from train.ppo import Batch

    steps, size = 3, parts.layout.size
    x, own_x = torch.randn(steps, 1, size), torch.randn(1, size)
    reward = torch.tensor([[1.0], [0.5], [-1.0]])
    never = torch.zeros(steps, 1, dtype=torch.bool)
    own = never.clone()
    own[-1] = True
    batch = Batch(obs=x, action=torch.zeros(steps, 1, len(parts.low)), log_prob=torch.zeros(steps, 1), reward=reward,
                  done=never, terminated=never, valid=~never, own_next=own, own_next_obs=own_x,
                  episode_returns=np.zeros(0), episode_lengths=np.zeros(0))  # fmt: skip
    advantage = learner.advantages(batch, x, own_x)["advantage"][:, 0]
    with torch.no_grad():
        value = parts.critic_net(x[:, 0]).squeeze(-1)
        following = torch.cat([value[1:], parts.critic_net(own_x).squeeze(-1)])
    delta, expected, running = reward[:, 0] + 0.9 * following - value, torch.zeros(steps), 0.0
    for t in reversed(range(steps)):
        running = delta[t] + 0.9 * 0.8 * running
        expected[t] = running
    assert torch.allclose(advantage, expected, atol=1e-5)


def test_the_ppo_settings_reach_the_sb3_model():
    from train.config import load_config
    from train.sb3_ppo import build_model, make_vec_env

    cfg = load_config("platoon", overrides={"envs": 2, "scenarios": "adaptive:a01_straight_free", "lib": "sb3",
                                            "gamma": 0.9, "gae_lambda": 0.8, "clip_epsilon": 0.3,
                                            "entropy_coeff": 0.02, "critic_coeff": 0.7, "lr": 3e-4, "epochs": 3,
                                            "frames_per_batch": 256, "minibatch_size": 32, "target_kl": 0.03,
                                            "max_grad_norm": 0.4, "hidden": [32, 16], "init_log_std": [-1.0, -0.3]})  # fmt: skip
    vec = make_vec_env(cfg)
    try:
        model = build_model(cfg, vec)
    finally:
        vec.close()
    assert (model.gamma, model.gae_lambda, model.clip_range(1.0), model.ent_coef, model.vf_coef) == pytest.approx(
        (0.9, 0.8, 0.3, 0.02, 0.7)
    )
    assert (model.n_epochs, model.batch_size, model.n_steps * vec.num_envs) == (3, 32, 256)
    assert model.target_kl == pytest.approx(0.03) and model.max_grad_norm == pytest.approx(0.4)
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(3e-4)
    assert model.policy.net_arch == [32, 16]
    assert model.policy.log_std.tolist() == pytest.approx([-1.0, -0.3])


def test_epochs_and_minibatches_set_the_number_of_updates(tmp_path):
    args = ["ppo", "--task", "platoon", "--scenarios", "adaptive:a01_straight_free", "--total-steps", "64",
            "--frames-per-batch", "64", "--minibatch-size", "16", "--epochs", "3", "--target-kl", "0",
            "--envs", "1", "--eval-episodes", "0", "--out-dir", str(tmp_path / "run"), "--quiet"]  # fmt: skip
    assert main(args) == 0
    state = torch.load(tmp_path / "run" / "final.pt", weights_only=True)["optimizer"]["state"]
    assert {int(s["step"]) for s in state.values()} == {3 * 64 // 16}  # every parameter: 12 Adam steps


def test_workers_may_hold_copies_with_different_agent_counts():
    """adaptive's first two scenarios (one follower, then two), one copy per worker process: each
    worker steps its share as one simulation of the core, so shares need not be equal, and the
    slots play what they play in this process."""
    from train.config import load_config
    from train.ppo import make_env

    cfg = load_config("platoon", overrides={"envs": 2, "workers": 2})
    split, here = make_env(cfg), make_env(cfg.model_copy(update={"workers": 0}))
    try:
        assert split.batch_size == here.batch_size == torch.Size([3])
        assert [len(shard.slots) for shard in split.base_env.driving.shards] == [1, 2]
        torch.manual_seed(0)
        a = split.rollout(40, break_when_any_done=False)
        torch.manual_seed(0)
        b = here.rollout(40, break_when_any_done=False)
        assert (a == b).all() and a["next", "reward"].abs().sum() > 0
    finally:
        split.close()
        here.close()


def _platoon_parts(envs: int, **overrides):
    from train.config import load_config

    cfg = load_config("platoon", overrides={"envs": envs, "workers": 0, "scenarios": "adaptive:a01_straight_free,"
                                            "adaptive:a02_straight_two_followers_low", **overrides})  # fmt: skip
    return cfg


@pytest.mark.parametrize("workers", [0, 2])
def test_the_slot_collector_plays_what_the_torchrl_env_plays(workers):
    """The collector on the flat buffers against the TorchRL env over the same copies and seed,
    driven by the collector's own actions: the same observations the policy acted on, valid
    flags, rewards, ends and next observations (the final one where an episode ended), over
    several episode ends and the batch's last step, so both trainers learn from the same data.
    With two workers the env steps in two parts and the policy acts for one while the other
    steps; the data must be the same as in lockstep."""
    from train.ppo import Inference, SlotCollector, driving_parts, make_driving, make_env

    cfg = _platoon_parts(3, controller="direct", init_log_std=[0.5])  # wide raw actions: crashes, waits, restarts
    driving = make_driving(cfg.model_copy(update={"workers": workers}))
    env = make_env(cfg)
    try:
        assert len(driving.parts) == (2 if workers == 2 else 1)
        parts = driving_parts(driving, cfg)
        parts.normalizer.update(torch.randn(256, parts.layout.size) * 2.0 + 0.5)
        policy = Inference(parts, torch.device("cpu"), seed=3)
        policy.sync(parts)
        batch = SlotCollector(driving, parts.layout, policy, torch.device("cpu")).collect(150)
        assert bool(batch.done.any()) and not bool(batch.valid.all())  # ends and waiting slots
        td = env.reset()
        flat = parts.layout.flatten
        steps, slots, _ = batch.obs.shape
        next_obs = []
        for t in range(steps):
            assert torch.equal(flat(dict(td["observation"].items())), batch.obs[t]), t
            assert torch.equal(td["valid"][:, 0], batch.valid[t]), t
            td = env.step(td.set("action", batch.action[t].clone()))
            nxt = td["next"]
            assert torch.equal(nxt["reward"][:, 0], batch.reward[t]), t
            assert torch.equal(nxt["done"][:, 0], batch.done[t]) and torch.equal(
                nxt["terminated"][:, 0], batch.terminated[t]
            )
            next_obs.append(flat(dict(nxt["observation"].items())))
            td = env.step_mdp(td)
            if bool(td["done"].any()):
                td = env.reset(td.set("_reset", td["done"].clone()))
        following = torch.stack(next_obs)
        assert torch.equal(batch.own_next_obs, following[batch.own_next])
        assert bool(batch.own_next[-1].all())
        not_own = ~batch.own_next[:-1] & batch.valid[:-1]
        assert torch.equal(following[:-1][not_own], batch.obs[1:][not_own])  # else the next step's own observation
        ended = batch.done & batch.valid
        assert len(batch.episode_returns) == int(ended.sum())
    finally:
        driving.close()
        env.close()


def test_the_update_reads_the_values_and_log_probabilities_of_the_acting_policy():
    """The learner's values (one critic pass, the next value taken from the following step where
    it is the slot's own) equal a critic pass over every next observation, and the loss's actor
    scores an action as the acting copy did."""
    from train.ppo import FLAT_OBSERVATION, Inference, Learner, SlotCollector, driving_parts, loss_modules, make_driving

    cfg = _platoon_parts(2)
    driving = make_driving(cfg)
    try:
        parts = driving_parts(driving, cfg)
        parts.normalizer.update(torch.randn(256, parts.layout.size) * 2.0 + 0.5)
        policy = Inference(parts, torch.device("cpu"), seed=1)
        policy.sync(parts)
        batch = SlotCollector(driving, parts.layout, policy, torch.device("cpu")).collect(120)
    finally:
        driving.close()
    learner = Learner(cfg, parts, torch.device("cpu"))
    with torch.no_grad():
        x = parts.normalizer(batch.obs)
        value, next_value = learner._values(x, parts.normalizer(batch.own_next_obs), batch.own_next)
        expected = parts.critic_net(x).squeeze(-1)
        following = torch.cat([x[1:], x[-1:]])  # not used where own_next
        following[batch.own_next] = parts.normalizer(batch.own_next_obs)
        expected_next = parts.critic_net(following).squeeze(-1)
        actor, _ = loss_modules(parts)
        dist = actor.get_dist(
            TensorDict({FLAT_OBSERVATION: x.reshape(-1, x.shape[-1])}, batch_size=[x.shape[0] * x.shape[1]])
        )
        log_prob = dist.log_prob(batch.action.reshape(-1, batch.action.shape[-1]))
    assert torch.allclose(value, expected, atol=1e-5) and torch.allclose(next_value, expected_next, atol=1e-5)
    assert torch.allclose(log_prob, batch.log_prob.reshape(-1), atol=1e-4)


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
@pytest.mark.parametrize("device", ["torch-cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA GPU"))])  # fmt: skip
def test_the_learner_runs_on_the_named_device_with_the_simulations_on_cpu_workers(tmp_path, lib, device):
    """``--device``: inference and updates on that device (torch-cpu: the GPU's code path, explicit
    transfers included, on the CPU), the copies in a worker process; the checkpoint is plain CPU
    tensors that evaluation loads anywhere."""
    out = tmp_path / "run"
    args = ["ppo", "--task", "platoon", "--lib", lib, "--device", device, "--workers", "1", "--scenarios",
            "adaptive:a01_straight_free", "--total-steps", "128", "--frames-per-batch", "64", "--minibatch-size", "32",
            "--epochs", "2", "--envs", "2", "--eval-episodes", "0", "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    blob = torch.load(out / "final.pt", weights_only=True)
    assert blob["step"] == 128 and blob["config"]["device"] == device
    weights = blob["actor"] if lib == "torchrl" else blob["policy"]
    assert all(t.device.type == "cpu" for t in weights.values())
    assert np.isfinite(blob["metrics"]["loss/objective"])
