"""The paper's cost on hand-made descriptors: known triplets give known costs."""

import pytest
import torch
from torch import nn

from training.losses import DescriptorLoss, pair_cost, triplet_cost, weight_decay

F = torch.tensor([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [0.0, 4.0], [0.0, 0.0]])


def idx(*v: int) -> torch.Tensor:
    return torch.tensor(v)


def test_satisfied_triplet_costs_nothing():
    # ||f0 - f2|| = 3 > ||f0 - f1|| + m: the ratio exceeds 1
    assert float(triplet_cost(F, idx(0), idx(1), idx(2))) == pytest.approx(0.0)


def test_violated_triplet_cost_is_the_ratio():
    # anchor 0, similar 2 (distance 3), dissimilar 1 (distance 1): 1 - 1 / (3 + 0.01)
    assert float(triplet_cost(F, idx(0), idx(2), idx(1))) == pytest.approx(1 - 1 / 3.01, abs=1e-6)
    # the mean over two triplets: (1 - 3/4.01) and 0
    both = triplet_cost(F, idx(0, 0), idx(3, 1), idx(2, 3))
    assert float(both) == pytest.approx((1 - 3 / 4.01 + 0.0) / 2, abs=1e-6)


def test_margin_enters_the_denominator():
    # equal distances: 1 - 1 / (1 + m)
    f = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert float(triplet_cost(f, idx(0), idx(1), idx(2), margin=0.5)) == pytest.approx(1 - 1 / 1.5, abs=1e-6)


def test_collapsed_dissimilar_pair_still_gets_pushed_apart():
    f = F.clone().requires_grad_(True)
    cost = triplet_cost(f, idx(0), idx(1), idx(4))  # f4 == f0: distance 0
    assert cost.item() == pytest.approx(1.0, abs=1e-3)
    cost.backward()
    g = f.grad
    assert torch.isfinite(g).all()
    assert float(g[4].abs().sum()) > 0 or float(g[0].abs().sum()) > 0


def test_pair_cost_is_squared_distance():
    assert float(pair_cost(F, idx(0, 1), idx(3, 2))) == pytest.approx((16 + 4) / 2)


def test_weight_decay_ignores_biases():
    net = nn.Sequential(nn.Linear(3, 2))
    with torch.no_grad():
        net[0].weight.fill_(2.0)
        net[0].bias.fill_(100.0)
    assert float(weight_decay(net)) == pytest.approx(6 * 4.0)


def test_total_cost_and_terms():
    net = nn.Sequential(nn.Linear(1, 1, bias=False))
    with torch.no_grad():
        net[0].weight.fill_(1.0)
    loss = DescriptorLoss(decay=0.5)
    total, terms = loss(net, F, torch.tensor([[0, 2, 1]]), torch.tensor([[0, 1]]))
    assert terms["triplet"] == pytest.approx(1 - 1 / 3.01, abs=1e-6)
    assert terms["pair"] == pytest.approx(1.0)
    assert float(total) == pytest.approx(1 - 1 / 3.01 + 1.0 + 0.5, abs=1e-6)
