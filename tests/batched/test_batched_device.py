"""The batched backend's torch stages: on any torch device they drive the copies as the compiled
kernels do (checked on the CPU here, and on a GPU where one is visible)."""

import numpy as np
import pytest
import torch

from smarts.env.batched import BatchedDriving
from tests.batched.test_batched_backend import PLATOON, _adaptive, _platoon_reward

DEVICES = [
    "torch-cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU visible")),
]


def _rollout(device: str, controller: str, steps: int = 200) -> tuple[BatchedDriving, np.ndarray]:
    specs = _adaptive("a01_straight_free", "a02_straight_two_followers_low", "a09_lead_turns_right_at_signal_medium",
                      controller=controller) * 2  # fmt: skip
    batch = BatchedDriving(specs, observation=PLATOON, reward_factory=_platoon_reward(), sim_device=device)
    batch.set_seed(5)
    batch.reset()
    rng = np.random.default_rng(1)
    box = batch.action_space
    egos = []
    for _ in range(steps):
        res = batch.step(rng.uniform(box.low, box.high, size=(batch.num_slots, box.shape[0])))
        egos.append(res.obs["ego"].copy())
    return batch, np.array(egos)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("controller", ["lane_relative", "direct"])
def test_the_torch_pose_stage_drives_the_copies_as_the_compiled_kernel(device, controller):
    batch, torch_egos = _rollout(device, controller)
    provider = batch.groups[0].sim.providers[0]
    assert provider.device is not None and provider.device.type == torch.device(device.replace("torch-", "")).type
    cpu_batch, egos = _rollout("cpu", controller)
    assert cpu_batch.groups[0].sim.providers[0].device is None  # the compiled kernels
    np.testing.assert_allclose(torch_egos, egos, rtol=1e-6, atol=1e-6)
    assert np.abs(egos[-1] - egos[0]).max() > 1.0  # the copies moved


def test_an_unknown_device_is_refused_naming_it():
    with pytest.raises(ValueError, match="device"):
        BatchedDriving(_adaptive("a01_straight_free"), observation=PLATOON, sim_device="tpu")
