"""Checkpoint files under hostile edits: each field is validated (type, size limit, finite bounds)
before any network is built, and the error names the file and the field. Every case starts from a
shipped checkpoint (read, edited in memory, written to a temporary file; the shipped file is never
touched)."""

from __future__ import annotations

import copy
import math
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from agents.checkpoint import MAX_FILE_BYTES, MAX_PARAMETERS, CheckpointError
from agents.loader import load_policy_file
from agents.planners.nets import KINDS, SCHEMAS, load_net
from zoo.registry import ZOO_DIR

SHIPPED = ZOO_DIR / "checkpoints"


def shipped(name: str) -> dict:
    return torch.load(SHIPPED / name, weights_only=True)


def edited(tmp_path: Path, name: str, edit) -> Path:
    """A copy of a shipped checkpoint with ``edit(blob)`` applied, as a file."""
    blob = copy.deepcopy(shipped(name))
    edit(blob)
    path = tmp_path / f"edited-{name}"
    torch.save(blob, path)
    return path


def refused(load, path: Path, message: str) -> str:
    """The CheckpointError ``load(path)`` raises; it must name the file and hold ``message``."""
    with pytest.raises(CheckpointError) as raised:
        load(path)
    text = str(raised.value)
    assert text.startswith(f"{path}: ") and message in text, text
    assert "Traceback" not in text
    return text


PPO_CASES = [
    ("action.space missing", lambda b: b["action"].pop("space"), "action.space: required field missing"),
    ("layout.keys missing", lambda b: b["layout"].pop("keys"), "layout.keys: required field missing"),
    ("actor missing", lambda b: b.pop("actor"), "actor: required field missing"),
    (
        "hidden of 10**9 units",
        lambda b: b.update(hidden=[10**9]),
        "hidden[0]: input should be less than or equal to 8192",
    ),
    ("hidden as text", lambda b: b.update(hidden="128"), "hidden: input should be a valid list"),
    (
        "NaN action bound",
        lambda b: b["action"]["low"].__setitem__(0, math.nan),
        "action.low[0]: input should be a finite number",
    ),
    (
        "infinite action bound",
        lambda b: b["action"]["high"].__setitem__(1, math.inf),
        "action.high[1]: input should be a finite number",
    ),
    ("bounds of two lengths", lambda b: b["action"].update(high=[1.0]), "action: low has 2 numbers, high 1"),
    ("low above high", lambda b: b["action"].update(low=[2.0, 2.0]), "action: low [2.0, 2.0] exceeds high [1.0, 1.0]"),
    ("layout keys and shapes disagree", lambda b: b["layout"]["shapes"].pop(), "layout: 10 keys but 9 shapes"),
    (
        "a negative shape",
        lambda b: b["layout"]["shapes"].__setitem__(0, [-5]),
        "layout.shapes[0][0]: input should be greater than or equal to 1",
    ),
    (
        "a weight that is not a tensor",
        lambda b: b["actor"].update({"net.0.weight": [1.0]}),
        "actor['net.0.weight']: input should be a tensor",
    ),
    (
        "NaN weights",
        lambda b: b["actor"]["net.0.weight"].fill_(math.nan),
        "actor: tensor 'net.0.weight' holds NaN or infinite values",
    ),
    (
        "NaN observation statistics",
        lambda b: b["normalizer"]["var"].fill_(math.inf),
        "normalizer: tensor 'var' holds NaN",
    ),
    ("unknown field", lambda b: b.update(hiden=[128]), "hiden: unknown field"),
    (
        "unknown mean map",
        lambda b: b["action"].update(mean="sigmoid"),
        "action.mean: input should be 'linear' or 'tanh'",
    ),
    ("negative step", lambda b: b.update(step=-1), "step: input should be greater than or equal to 0"),
]


@pytest.mark.parametrize("name, edit, message", PPO_CASES, ids=[c[0] for c in PPO_CASES])
def test_a_ppo_checkpoint_field_is_refused_naming_the_file_and_field(tmp_path, name, edit, message):
    refused(load_policy_file, edited(tmp_path, "platoon-rtp.pt", edit), message)


def test_a_network_too_large_is_refused_before_it_is_built(tmp_path):
    """Widths within the per-layer limit but a network of more than MAX_PARAMETERS numbers: refused
    from the recorded sizes alone (quickly; building it would take gigabytes)."""
    path = edited(tmp_path, "platoon-rtp.pt", lambda b: b.update(hidden=[8192] * 16))
    start = time.perf_counter()
    text = refused(load_policy_file, path, "hidden: a network of")
    assert f"at most {MAX_PARAMETERS:,}" in text and time.perf_counter() - start < 5.0


PLANNER_CASES = [
    ("state_dict missing", "tf-stop-move", lambda b: b.pop("state_dict"), "state_dict: required field missing"),
    ("config missing", "aid-predictor", lambda b: b.pop("config"), "config: required field missing"),
    (
        "unknown config field",
        "tf-stop-move",
        lambda b: b["config"].update(dropout=0.5),
        "config.dropout: unknown field (known: hidden, layers, inputs)",
    ),
    (
        "config that is a list",
        "vcr-classifier",
        lambda b: b.update(config=[3, 64, 24, 6]),
        "config: input should be a mapping, got [3, 64, 24, 6]",
    ),
    ("config that is text", "aid-predictor", lambda b: b.update(config="d=64"), "config: input should be a mapping"),
    (
        "a huge layer",
        "tf-stop-move",
        lambda b: b["config"].update(hidden=10**7),
        "config.hidden: input should be less than or equal to 8192",
    ),
    (
        "a huge attention width",
        "aid-predictor",
        lambda b: b["config"].update(d=2**20),
        "config.d: input should be less",
    ),
    (
        "heads that do not divide the width",
        "aid-predictor",
        lambda b: b["config"].update(heads=3),
        "config: d (64) must be even and a multiple of heads (3)",
    ),
    (
        "a NaN dropout",
        "aid-predictor",
        lambda b: b["config"].update(dropout=math.nan),
        "config.dropout: input should be",
    ),
    (
        "a raster too small for the convolutions",
        "vcr-classifier",
        lambda b: b["config"].update(size=8),
        "config.size: input should be greater than or equal to 31",
    ),
    (
        "a bool for a count",
        "tf-stop-move",
        lambda b: b["config"].update(layers=True),
        "config.layers: input should be a valid integer",
    ),
    (
        "an all-NaN net",
        "tf-stop-move",
        lambda b: b.update(state_dict={k: torch.full_like(v, math.nan) for k, v in b["state_dict"].items()}),
        "state_dict: tensor 'net.0.weight' holds NaN or infinite values; weights must be finite",
    ),
    (
        "one infinite weight",
        "vcr-classifier",
        lambda b: b["state_dict"]["head.0.bias"].__setitem__(0, math.inf),
        "state_dict: tensor 'head.0.bias' holds NaN",
    ),
]


@pytest.mark.parametrize("name, kind, edit, message", PLANNER_CASES, ids=[c[0] for c in PLANNER_CASES])
def test_a_planner_checkpoint_field_is_refused_naming_the_file_and_field(tmp_path, name, kind, edit, message):
    refused(lambda p: load_net(p, kind), edited(tmp_path, f"{kind}.pt", edit), message)


def test_a_huge_planner_network_is_refused_from_its_config_before_it_is_built(tmp_path):
    path = edited(tmp_path, "tf-stop-move.pt", lambda b: b["config"].update(hidden=8192, layers=16))
    start = time.perf_counter()
    text = refused(lambda p: load_net(p, "tf-stop-move"), path, "config: a network of 1,007,")
    assert f"at most {MAX_PARAMETERS:,}" in text and time.perf_counter() - start < 5.0


def test_the_zoo_planners_refuse_a_network_of_other_inputs(tmp_path):
    """A valid file trained for other inputs than the planner gives it is refused at load, not in
    the middle of an episode."""
    from zoo.planners import EventRisk, StopMoveVote

    def narrower(blob):
        blob["config"]["inputs"] = 40
        blob["state_dict"]["net.0.weight"] = blob["state_dict"]["net.0.weight"][:, :40].clone()

    refused(StopMoveVote, edited(tmp_path, "tf-stop-move.pt", narrower), "config.inputs: the vote reads 40 features")
    refused(EventRisk, edited(tmp_path, "vcr-classifier.pt", lambda b: b["config"].update(size=65)), "config.size")


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_the_size_a_planner_config_states_is_the_size_of_its_network(kind):
    """The parameter count the size limit uses (computed without building anything) equals the
    network's own, for the shipped config and a differently shaped one."""
    config_type = SCHEMAS[kind].model_fields["config"].annotation
    shipped_config = shipped(f"{kind}.pt")["config"]
    other = {"aid-predictor": {"d": 32, "heads": 2, "ffn": 48, "rounds": 3, "dropout": 0.0},
             "tf-stop-move": {"hidden": 17, "layers": 2, "inputs": 9},
             "vcr-classifier": {"channels": 5, "size": 45, "numbers": 7, "classes": 3}}[kind]  # fmt: skip
    for config in (shipped_config, other):
        net = KINDS[kind](**config)
        assert config_type(**config).parameters() == sum(t.numel() for t in net.state_dict().values())


def test_every_shipped_checkpoint_passes_its_schema():
    for name in ("platoon-rtp.pt", "platoon-c.pt", "drive.pt"):
        assert load_policy_file(SHIPPED / name).action_space
    for kind in KINDS:
        net, _ = load_net(SHIPPED / f"{kind}.pt", kind)
        assert all(bool(torch.isfinite(t).all()) for t in net.state_dict().values() if t.is_floating_point())


def test_a_compressed_archive_declaring_more_than_the_limit_is_refused_before_reading(tmp_path, monkeypatch):
    """torch reads deflated records too, so a small file can unpack to gigabytes: the sizes the
    archive declares are checked first. (The limit is lowered so that the test file stays small.)"""
    import agents.checkpoint

    plain, packed = tmp_path / "plain.pt", tmp_path / "packed.pt"
    torch.save({"x": torch.zeros(100_000)}, plain)  # 400 kB of zeros
    with zipfile.ZipFile(plain) as source, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as target:
        for info in source.infolist():
            target.writestr(info.filename, source.read(info.filename))
    assert packed.stat().st_size < 10_000
    monkeypatch.setattr(agents.checkpoint, "MAX_FILE_BYTES", 100_000)
    refused(load_policy_file, packed, "the archive declares 40")
    monkeypatch.setattr(agents.checkpoint, "MAX_FILE_BYTES", MAX_FILE_BYTES)
    refused(load_policy_file, packed, "expected a checkpoint of format")  # within the limit: read, then judged


def test_a_refused_checkpoint_leaves_the_policy_usable_elsewhere(tmp_path):
    """Loading a bad file changes nothing for the good ones in the same process."""
    refused(load_policy_file, edited(tmp_path, "platoon-rtp.pt", lambda b: b.update(hidden=[10**9])), "hidden[0]")
    policy = load_policy_file(SHIPPED / "platoon-rtp.pt")
    obs = {k: np.zeros((2, *shape), np.float32) for k, shape in zip(policy.layout.keys, policy.layout.shapes)}
    assert np.isfinite(policy.act(obs)).all()


def _sb3_export() -> dict:
    """A small SB3 export, as ``train.sb3_ppo.save_sb3`` writes one."""
    import gymnasium as gym
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    from agents.sb3_policy import SB3_FORMAT

    shapes = {"ego": [4], "lead": [2, 3]}
    space = gym.spaces.Dict({k: gym.spaces.Box(-np.inf, np.inf, tuple(v), np.float32) for k, v in shapes.items()})
    policy = MultiInputActorCriticPolicy(
        space, gym.spaces.Box(-1.0, 1.0, (2,), np.float32), lambda _: 0.0, net_arch=[8]
    )
    return {"format": SB3_FORMAT, "policy": policy.state_dict(), "observation": shapes, "net_arch": [8], "step": 0,
            "action": {"space": "relative_target_pose", "low": [-1.0, -1.0], "high": [1.0, 1.0]}}  # fmt: skip


SB3_CASES = [
    ("action missing", lambda b: b.pop("action"), "action: required field missing"),
    ("a huge layer", lambda b: b.update(net_arch=[10**9]), "net_arch[0]: input should be less than or equal to 8192"),
    (
        "a NaN bound",
        lambda b: b["action"]["high"].__setitem__(0, math.nan),
        "action.high[0]: input should be a finite number",
    ),
    (
        "a shape that is text",
        lambda b: b["observation"].update(ego="4"),
        "observation['ego']: input should be a valid list",
    ),
    ("NaN weights", lambda b: next(iter(b["policy"].values())).fill_(math.nan), "policy: tensor"),
]


@pytest.mark.parametrize("name, edit, message", SB3_CASES, ids=[c[0] for c in SB3_CASES])
def test_an_sb3_export_field_is_refused_naming_the_file_and_field(tmp_path, name, edit, message):
    blob = _sb3_export()
    assert load_policy_file(_saved(tmp_path / "good.pt", blob)).action_space == "relative_target_pose"
    edit(blob)
    refused(load_policy_file, _saved(tmp_path / "bad.pt", blob), message)


def _saved(path: Path, blob: dict) -> Path:
    torch.save(blob, path)
    return path
