"""Learning-rate groups by parameter-name prefix."""

from functools import partial

import pytest
import torch
from torch import nn

from tvrecon.models.optim import configure_optimizers, lr_scaled_groups


def _net() -> nn.Module:
    net = nn.Module()
    net.visual = nn.Linear(2, 2)
    net.fusion = nn.Sequential(nn.Linear(2, 2), nn.Linear(2, 2))
    return net


def test_prefix_groups_get_scaled_lr_and_cosine_keeps_the_ratio() -> None:
    net = _net()
    factory = partial(torch.optim.AdamW, lr=1e-3)
    groups = lr_scaled_groups(net.named_parameters(), factory, {"fusion": 10.0, "fusion.1": 2.0})
    assert [len(g["params"]) for g in groups] == [2, 2, 2]  # base, fusion.1 (longest prefix first), fusion
    assert "lr" not in groups[0] and groups[1]["lr"] == pytest.approx(2e-3) and groups[2]["lr"] == pytest.approx(1e-2)
    assert {id(p) for g in groups for p in g["params"]} == {id(p) for p in net.parameters()}
    sched = partial(torch.optim.lr_scheduler.CosineAnnealingLR, T_max=4)
    cfg = configure_optimizers(groups, factory, sched)
    opt, scheduler = cfg["optimizer"], cfg["lr_scheduler"]["scheduler"]
    opt.step()
    scheduler.step()
    lrs = [g["lr"] for g in opt.param_groups]
    assert lrs[2] / lrs[0] == pytest.approx(10.0)


def test_bad_scales_are_named() -> None:
    net = _net()
    with pytest.raises(ValueError, match="match no trainable parameter"):
        lr_scaled_groups(net.named_parameters(), partial(torch.optim.AdamW, lr=1e-3), {"tactile": 2.0})
    with pytest.raises(ValueError, match="must be > 0"):
        lr_scaled_groups(net.named_parameters(), partial(torch.optim.AdamW, lr=1e-3), {"fusion": 0.0})
    with pytest.raises(ValueError, match="base lr"):
        lr_scaled_groups(net.named_parameters(), partial(torch.optim.AdamW), {"fusion": 2.0})
