"""The batched core: B scenario copies stepped as one simulation (``smarts.core.simulation``),
with every learning agent of every copy a slot of plain arrays (:class:`BatchedDriving`). The
library adapters over it are ``smarts.env.torchrl_env.SmartsBatchedEnv`` (TorchRL) and
``smarts.env.sb3_vec_env.SmartsVecEnv`` (Stable-Baselines3)."""

from smarts.env.batched.driving import BatchedDriving, BatchedSetupError

__all__ = ["BatchedDriving", "BatchedSetupError"]
