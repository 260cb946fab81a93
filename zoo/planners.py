"""The planner zoo entries with their learned parts: the weights shipped under ``checkpoints/``.

``zoo:tf``, ``zoo:vcr`` and ``zoo:aid`` load their small networks here (weights only); the rule
forms (``zoo:tf-rules``, ``zoo:vcr-ttc``, ``zoo:aid-cv``) are the planner classes themselves.
Model cards: ``cards/tf.md``, ``cards/vcr.md``, ``cards/aid.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

CHECKPOINTS = Path(__file__).resolve().parent / "checkpoints"


def _from_file(planner, path: str | Path):
    """``planner`` with ``source``: the file its learned part came from (error messages name it, and
    the benchmark keys resumed episodes by its contents)."""
    planner.source = str(path)
    return planner


def aid(checkpoint: str | Path | None = None):
    """AID over its learned motion predictor."""
    from agents.planners.aid import AIDPlanner, LearnedPredictor

    path = checkpoint or CHECKPOINTS / "aid-predictor.pt"
    return _from_file(AIDPlanner(predictor=LearnedPredictor(path)), path)


class StopMoveVote:
    """TF's learned vote: 53 features -> True to move."""

    def __init__(self, path: str | Path):
        import torch

        from agents.checkpoint import CheckpointError
        from agents.planners.nets import load_net
        from agents.planners.tf import FEATURES

        self.torch = torch
        self.net, self.metrics = load_net(path, "tf-stop-move")
        if self.net.config["inputs"] != FEATURES:
            raise CheckpointError(f"{path}: config.inputs: the vote reads {self.net.config['inputs']} features, "
                                  f"agents.planners.tf.stop_move_features gives {FEATURES}: retrain it")  # fmt: skip

    def __call__(self, features: np.ndarray) -> bool:
        with self.torch.no_grad():
            logits = self.net(self.torch.as_tensor(features[None], dtype=self.torch.float32))
        return bool(logits[0].argmax() == 1)


def tf(checkpoint: str | Path | None = None):
    """TF's rules with the behaviour-cloned stop/move veto."""
    from agents.planners.tf import TFPlanner

    path = checkpoint or CHECKPOINTS / "tf-stop-move.pt"
    return _from_file(TFPlanner(stop_move=StopMoveVote(path)), path)


class EventRisk:
    """VCR's learned collision probability: rasters and the candidate's numbers -> P(collision)."""

    def __init__(self, path: str | Path):
        import torch

        from agents.planners.nets import load_net
        from agents.planners.vcr import NUMBERS, RASTERS

        self.torch = torch
        self.net, self.metrics = load_net(path, "vcr-classifier")
        config = self.net.config
        expected = {"numbers": NUMBERS, "channels": len(RASTERS["layers"]), "size": RASTERS["size"]}
        for field, value in expected.items():
            if config[field] != value:
                from agents.checkpoint import CheckpointError

                raise CheckpointError(f"{path}: config.{field}: the classifier was trained for {config[field]}, "
                                      f"agents.planners.vcr gives {value}: retrain it")  # fmt: skip

    def __call__(self, row: dict[str, np.ndarray], front: np.ndarray, plan: np.ndarray) -> float:
        from agents.planners.vcr import classifier_numbers

        torch = self.torch
        if "rasters" not in row:
            raise ValueError("zoo:vcr reads rasters: give the agent the interface of agents.planners.vcr.LEARNED_INTERFACE "
                             "(rasters: {size: 64, resolution: 0.8, layers: [drivable, route, occupancy]})")  # fmt: skip
        numbers = classifier_numbers(row, plan[0], plan)  # the candidate step, as VCR scores it
        with torch.no_grad():
            logits = self.net(torch.as_tensor(row["rasters"][None]), torch.as_tensor(numbers[None]))
        return float(torch.softmax(logits[0], -1)[0])


def vcr(checkpoint: str | Path | None = None):
    """VCR's follower with the learned event classifier over rasters."""
    from agents.planners.vcr import LEARNED_INTERFACE, VCRPlanner

    path = checkpoint or CHECKPOINTS / "vcr-classifier.pt"
    return _from_file(VCRPlanner(risk=EventRisk(path), interface=LEARNED_INTERFACE), path)
