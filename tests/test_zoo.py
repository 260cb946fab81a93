"""The zoo: every locator builds a policy that acts on the env's observations."""

import numpy as np
import pytest

import smarts.env  # noqa: F401
from zoo import ZOO, make_policy


@pytest.mark.parametrize("name", sorted(ZOO))
def test_every_zoo_agent_acts_in_its_action_space(name):
    """Each agent, in the env built as the benchmark builds it (its action space, controller and
    observation interface), returns actions of that env's action box."""
    from smarts.benchmark.agents import policy_setup, scenario_for
    from smarts.env import DrivingParallelEnv
    from smarts.scenario import load_scenario

    policy = make_policy(f"zoo:{name}")
    setup = policy_setup(policy, f"zoo:{name}")  # validates the recorded interface and lane-relative settings
    spec = scenario_for(load_scenario("straight_2lane_cruise"), setup)
    env = DrivingParallelEnv(spec, observation=setup.interface, lane_relative=setup.lane_relative)
    obs, _ = env.reset(seed=0)
    batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs["agent_0"]}
    action = np.asarray(policy.act(batch))
    box = env.action_space("agent_0")
    assert action.shape == (2, box.shape[0]) and np.isfinite(action).all()
    assert all(box.contains(a.astype(np.float32)) for a in action)
    assert policy.action_space in ("relative_target_pose", "continuous")
    env.close()


def test_zoo_cards_exist_for_checkpoints():
    from pathlib import Path

    import zoo.registry as registry

    for name, (module, target, _) in ZOO.items():
        if module == registry.CHECKPOINT:
            assert (registry.ZOO_DIR / target).is_file()
            card = registry.ZOO_DIR / "cards" / f"{name}.md"
            assert "S_bench" in card.read_text() and Path(target).stem == name
    assert "S_bench" in (registry.ZOO_DIR / "cards" / "stand-still.md").read_text()  # the reference floor


def test_unknown_locator_lists_the_known_ones():
    with pytest.raises(ValueError, match="zoo:keep-lane"):
        make_policy("zoo:teleporter")


def test_stand_still_brakes_gently_to_a_stop_in_its_lane(tmp_path):
    from smarts.benchmark.jobs import Job
    from smarts.benchmark.metrics import read_episode, score_episode
    from smarts.benchmark.runner import run_episode

    suite = tmp_path / "ramp.yaml"
    suite.write_text(
        "name: ramp\ntask: collaborative\nscenarios:\n  - name: ramp\n    difficulty: easy\n    time_limit: 12\n"
        "    scenario:\n      map: builtin:highway_merge_exit\n      agents:\n"
        "        - mission: {start: {road: ramp, offset: 80, speed: 10}, goal: {road: main_4, offset: 50}}\n"
    )
    result = run_episode(Job("zoo:stand-still", str(suite), 0, 0, 0, str(tmp_path / "log.npz")))
    straight_road = tmp_path / "straight.yaml"
    straight_road.write_text(
        suite.read_text()
        .replace("builtin:highway_merge_exit", "builtin:straight_2lane")
        .replace("road: ramp, offset: 80", "road: main, offset: 10")
        .replace("main_4, offset: 50", "main, offset: 250")
    )
    run_episode(Job("zoo:stand-still", str(straight_road), 0, 0, 0, str(tmp_path / "straight.npz")))
    assert score_episode(read_episode(tmp_path / "straight.npz"))["cost.comfort"] == 0.0
    assert result["failure"] is None and result["action_space"] == "relative_target_pose"
    log = read_episode(tmp_path / "log.npz")
    trace = log.agents["agent_0"]
    # Braking within the humanness comfort limits (configs/benchmark/metrics.yaml) on every row.
    assert np.abs(trace.accel_long).max() <= 2.0 and np.abs(trace.jerk_long).max() <= 0.9
    # Stopped, and stays stopped; it followed the curved ramp's lane while moving.
    stopped = np.flatnonzero(trace.speed == 0.0)
    straight = trace.time < 2.0  # before the ramp's polyline corner (a lateral spike for any lane follower)
    assert np.abs(trace.accel_lat[straight]).max() <= 1.47 and np.abs(trace.jerk_lat[straight]).max() <= 0.9
    assert stopped.size and (trace.speed[stopped[0] :] == 0.0).all() and trace.time[stopped[0]] < 10.5
    assert np.abs(trace.lane_offset).max() < 0.3 and not trace.off_road.any()
    assert np.ptp(trace.heading[: stopped[0]]) > 0.01  # the ramp curves: it steered along it
