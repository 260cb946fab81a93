"""The actor-critic's MLP is torchrl's ``MLP`` rebuilt from ``torch.nn`` (evaluation then never
imports torchrl): the same layers, keys and, for one seed, the same weights and random stream."""

import numpy as np
import pytest
import torch
from torch import nn

from agents.ppo import mlp


@pytest.mark.parametrize(("sizes", "out", "gain"), [([60, 128, 128], 3, 0.01), ([10, 16], 1, 1.0), ([7], 2, 1.0)])
def test_mlp_matches_torchrl_mlp_for_one_seed(sizes, out, gain):
    from torchrl.modules import MLP

    torch.manual_seed(3)
    ours = mlp(sizes, out, final_gain=gain)
    after_ours = torch.rand(4)
    torch.manual_seed(3)
    theirs = MLP(in_features=sizes[0], out_features=out, num_cells=list(sizes[1:]), activation_class=nn.Tanh)
    linears = [m for m in theirs if isinstance(m, nn.Linear)]
    for layer in linears:
        nn.init.orthogonal_(layer.weight, gain if layer is linears[-1] else np.sqrt(2))
        nn.init.zeros_(layer.bias)
    assert torch.equal(torch.rand(4), after_ours)
    a, b = ours.state_dict(), theirs.state_dict()
    assert list(a) == list(b)
    for key in a:
        assert torch.equal(a[key], b[key]), key
    x = torch.randn(5, sizes[0])
    assert torch.equal(ours(x), theirs(x))


def test_mlp_without_init_has_the_shape_to_load_weights_into():
    trained = mlp([6, 8], 2)
    loaded = mlp([6, 8], 2, init=False)
    loaded.load_state_dict(trained.state_dict())
    x = torch.randn(3, 6)
    assert torch.equal(loaded(x), trained(x))
