"""Seeds are checked where they are given, with errors naming the argument and the value."""

import re
import warnings

import numpy as np
import pytest

from smarts.core.simulation import SEED_MAX, check_seed, derived_seed
from smarts.env import DrivingParallelEnv
from smarts.env.assembly import build_simulation
from smarts.env.gym_env import DrivingEnv
from smarts.env.sb3_vec_env import SmartsVecEnv
from smarts.env.torchrl_env import SmartsBatchedEnv, SmartsTorchRLEnv
from tests.builders import agent, make_spec

BAD = [
    (-1, r"got -1 \(negative\)"),
    (1.5, r"got 1\.5 \(of type float\)"),
    (2.0, r"got 2\.0 \(of type float\)"),  # a whole float is not silently taken
    (True, r"got True \(a bool\)"),
    (np.bool_(False), r"got np\.False_ \(a bool\)"),
    ("7", r"got '7' \(of type str\)"),
    (2**64, r"got 18446744073709551616 \(too large for numpy's seed words and torch\.manual_seed\)"),
]
EXPECTED = r"expected an integer from 0 to 2\*\*64 - 1, "


def _spec():
    return make_spec([agent()], episode_steps=20)


@pytest.fixture(scope="module")
def envs():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        built = {
            "DrivingParallelEnv.reset(seed=...)": DrivingParallelEnv(_spec()),
            "DrivingEnv.reset(seed=...)": DrivingEnv(_spec()),
            "SmartsTorchRLEnv.set_seed(seed)": SmartsTorchRLEnv(_spec()),
            "SmartsBatchedEnv.set_seed(seed)": SmartsBatchedEnv([_spec(), _spec()]),
            "SmartsVecEnv.seed(seed)": SmartsVecEnv.from_scenario(_spec(), n_envs=2),
        }
    yield built
    for env in built.values():
        env.close()


def _seed(what, env, seed):
    if what.startswith(("DrivingParallelEnv", "DrivingEnv")):
        return env.reset(seed=seed)
    if what.startswith("SmartsVecEnv"):
        return env.seed(seed)
    return env.set_seed(seed)


@pytest.mark.parametrize("seed, problem", BAD, ids=[repr(s) for s, _ in BAD])
@pytest.mark.parametrize(
    "what",
    [
        "DrivingParallelEnv.reset(seed=...)",
        "DrivingEnv.reset(seed=...)",
        "SmartsTorchRLEnv.set_seed(seed)",
        "SmartsBatchedEnv.set_seed(seed)",
        "SmartsVecEnv.seed(seed)",
    ],
)
def test_bad_seeds_are_refused_naming_the_argument_and_the_value(envs, what, seed, problem):
    with pytest.raises(ValueError, match=re.escape(what) + ": " + EXPECTED + problem):
        _seed(what, envs[what], seed)


def test_a_refused_reset_seed_leaves_the_env_as_it_was():
    env = DrivingParallelEnv(_spec())
    env.reset(seed=4)
    env.step({"agent_0": np.array([1.0, 0.0, 0.0])})
    x, step = env.sim.table.x.copy(), env.sim.step_count
    with pytest.raises(ValueError, match=r"reset\(seed=\.\.\.\).*got -1"):
        env.reset(seed=-1)
    assert env.sim.seed == 4 and env.sim.step_count == step
    np.testing.assert_array_equal(env.sim.table.x, x)
    env.reset()  # None: the last seed again
    assert env.sim.seed == 4
    env.close()


@pytest.mark.parametrize("seed", [0, np.int64(3), np.uint64(SEED_MAX), SEED_MAX])
def test_integers_of_the_whole_range_are_seeds(envs, seed):
    for what, env in envs.items():
        _seed(what, env, seed)
    assert envs["DrivingParallelEnv.reset(seed=...)"].sim.seed == int(seed)
    assert envs["DrivingEnv.reset(seed=...)"].sim.seed == int(seed)


def test_seed_counts_wrap_past_the_top():
    assert derived_seed(SEED_MAX, 1) == 0 and derived_seed(5, 2) == 7
    env = SmartsTorchRLEnv(_spec())
    env.set_seed(SEED_MAX)
    env.reset()
    assert env.env.sim.seed == SEED_MAX
    env.reset()
    assert env.env.sim.seed == 0
    env.close()
    vec = SmartsVecEnv.from_scenario(_spec(), n_envs=2)
    assert vec.seed(SEED_MAX) == [SEED_MAX, 100_002]  # copy 1 starts 100_003 on (the one rule), wrapped
    vec.reset()
    assert list(vec.driving.groups[0].sim.episode_seed) == [SEED_MAX, 100_002]
    vec.reset()
    assert list(vec.driving.groups[0].sim.episode_seed) == [0, 100_003]
    vec.close()


def test_constructors_and_the_simulation_name_their_seed():
    with pytest.raises(ValueError, match=r"SmartsVecEnv\(seed=\.\.\.\): " + EXPECTED + r"got -3 \(negative\)"):
        SmartsVecEnv.from_scenario(_spec(), seed=-3)
    spec = _spec().model_copy(update={"seed": -2})  # a copy made without validation: the simulation checks too
    with pytest.raises(ValueError, match=r"test-scenario: seed: " + EXPECTED + r"got -2"):
        build_simulation(spec)
    sim = build_simulation(_spec())
    with pytest.raises(ValueError, match=r"Simulation\.reset\(seed=\.\.\.\): " + EXPECTED + r"got 0\.5"):
        sim.reset(seed=0.5)
    assert check_seed(np.uint8(9)) == 9 and type(check_seed(np.uint8(9))) is int
