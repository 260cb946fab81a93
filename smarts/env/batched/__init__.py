"""The batched backend: B episodes stepped as one vectorised simulation (``smarts.core.batched``),
with observations and rewards built once for all of them, as a numpy vector env
(:class:`BatchedDriving`), a TorchRL env (:class:`BatchedTorchRLEnv`) and an SB3 VecEnv
(:class:`BatchedVecEnv`)."""

from smarts.env.batched.driving import BatchedDriving, BatchedSetupError

__all__ = ["BatchedDriving", "BatchedSetupError"]
