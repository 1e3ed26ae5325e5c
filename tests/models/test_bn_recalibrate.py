"""recalibrate_batchnorm: the running statistics become the batches' own, nothing else of the network changes."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tvrecon.models.bn_recalibrate import recalibrate_batchnorm


def _net() -> nn.Sequential:
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(3, 3), nn.BatchNorm1d(3, momentum=0.1), nn.Dropout(0.5))
    with torch.no_grad():
        net[0].weight.copy_(torch.eye(3))
        net[0].bias.zero_()
        net[1].running_mean.fill_(100.0)  # stale statistics, far from the data's
        net[1].running_var.fill_(1e-4)
    return net


def test_statistics_become_the_batches_average_and_nothing_else_changes() -> None:
    net = _net()
    weights = {k: v.clone() for k, v in net.state_dict().items() if "running" not in k and "num_batches" not in k}
    g = torch.Generator().manual_seed(1)
    mean, std = torch.tensor([1.0, -2.0, 0.5]), torch.tensor([0.5, 2.0, 1.0])
    batches = [mean + std * torch.randn(256, 3, generator=g) for _ in range(8)]
    net.train()
    layers = recalibrate_batchnorm(net, batches, net, num_batches=8)
    assert layers == 1
    data = torch.cat(batches)
    # momentum=None: the plain average of the 8 batch means / unbiased variances
    assert torch.allclose(net[1].running_mean, torch.stack([b.mean(0) for b in batches]).mean(0), atol=1e-5)
    assert torch.allclose(net[1].running_mean, data.mean(0), atol=1e-5)
    assert torch.allclose(net[1].running_var, torch.stack([b.var(0) for b in batches]).mean(0), rtol=1e-4)
    assert torch.allclose(net[1].running_var.sqrt(), std, rtol=0.1)
    assert net[1].momentum == 0.1 and net.training and net[1].training  # restored
    for k, v in weights.items():
        assert torch.equal(net.state_dict()[k], v), k
    # in eval mode the layer now standardises data of that distribution
    net.eval()
    out = net(data)
    assert torch.allclose(out.mean(0), torch.zeros(3), atol=1e-4)
    assert torch.allclose(out.std(0), torch.ones(3), atol=1e-2)


def test_only_the_first_batches_are_used_and_dropout_stays_off() -> None:
    net = _net()
    seen: list[bool] = []

    def forward(x: torch.Tensor) -> torch.Tensor:
        seen.append(net[2].training)
        return net(x)

    batches = [torch.full((4, 3), float(i)) + torch.randn(4, 3) for i in range(10)]
    recalibrate_batchnorm(net.eval(), batches, forward, num_batches=3)
    assert seen == [False, False, False]  # 3 of the 10 batches, the rest of the network in eval mode
    assert not net.training and not net[1].training
    assert torch.allclose(net[1].running_mean, torch.stack([b.mean(0) for b in batches[:3]]).mean(0), atol=1e-5)


def test_bad_input_is_refused_and_changes_nothing() -> None:
    net = _net()
    with pytest.raises(ValueError, match="num_batches must be >= 1"):
        recalibrate_batchnorm(net, [torch.randn(4, 3)], net, num_batches=0)
    with pytest.raises(ValueError, match="empty"):
        recalibrate_batchnorm(net, [], net, num_batches=4)
    assert float(net[1].running_mean[0]) == 100.0  # the stored statistics are untouched
    assert recalibrate_batchnorm(nn.Linear(3, 3), [torch.randn(4, 3)], lambda x: x, 1) == 0  # no BatchNorm: a no-op
