"""The batched backend: B episodes stepped as one vectorised simulation (``smarts.core.batched``),
with observations and rewards built once for all of them, as a numpy vector env
(:class:`BatchedDriving`), a TorchRL env (``smarts.env.batched.torchrl_env.BatchedTorchRLEnv``) and
an SB3 VecEnv (``smarts.env.batched.sb3_vec_env.BatchedVecEnv``)."""

from smarts.env.batched.driving import BatchedDriving, BatchedSetupError

__all__ = ["BatchedDriving", "BatchedSetupError"]
