"""recalibrate_batchnorm: the running statistics become the batches' own, nothing else of the network changes."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from torch import nn
from torch.utils.data import DataLoader

from tvrecon.train.bn_recalibrate import (
    PreciseBatchNorm,
    batchnorm_statistics,
    recalibrate_batchnorm,
    statistics_shift,
)


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
    before = batchnorm_statistics(net)
    layers = recalibrate_batchnorm(net, batches, net, num_batches=8)
    # stored mean 100, std 0.01 against the data's means 1 / -2 / 0.5 and std 0.5 / 2 / 1: in eval mode the first
    # channel's output would sit (100 - 1) / 0.01 stored std off and the second spread 200x too wide
    [(group, shift)] = statistics_shift(before, batchnorm_statistics(net), depth=1).items()
    assert group == "1" and shift["layers"] == 1
    stored_std = (torch.tensor(1e-4) + 1e-5).sqrt()
    data_mean, data_std = net[1].running_mean, (net[1].running_var + 1e-5).sqrt()
    assert shift["mean_shift"] == pytest.approx(float(((100 - data_mean) / stored_std).max()), rel=1e-5)
    assert shift["std_ratio"] == pytest.approx(float(data_std.max() / stored_std), rel=1e-5)
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


class _Recon(L.LightningModule):
    """A reconstruction-like module: forward(batch, mask), a training_mask that draws from torch's random state."""

    def __init__(self) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4), nn.ReLU(), nn.Linear(4, 1))

    def training_mask(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return torch.rand(len(batch["x"])) < 0.5

    def forward(self, batch: dict[str, torch.Tensor], mask: torch.Tensor) -> torch.Tensor:
        return self.body(batch["x"] * (1 + mask[:, None].float()))

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return ((self(batch, self.training_mask(batch)) - batch["y"]) ** 2).mean()

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        self.log("val/loss", ((self(batch, torch.ones(len(batch["x"]), dtype=torch.bool)) - batch["y"]) ** 2).mean())

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.1)


class _Pairs(torch.utils.data.Dataset):
    def __init__(self, n: int = 64) -> None:
        g = torch.Generator().manual_seed(0)
        self.x, self.y = 3 + 2 * torch.randn(n, 3, generator=g), torch.randn(n, 1, generator=g)

    def __len__(self) -> int:
        return len(self.x)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return {"x": self.x[i], "y": self.y[i]}


def _fit(tmp_path, callbacks: list[L.Callback], shuffle: bool) -> _Recon:  # noqa: ANN001
    torch.manual_seed(0)
    module = _Recon()
    trainer = L.Trainer(
        max_epochs=2, callbacks=callbacks, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        default_root_dir=tmp_path, num_sanity_val_steps=1,
    )  # fmt: skip
    train = DataLoader(_Pairs(), batch_size=8, shuffle=shuffle)
    trainer.fit(module, train, DataLoader(_Pairs(16), batch_size=8))
    return module


def test_precise_batchnorm_leaves_training_alone_and_keeps_the_final_weights_statistics(tmp_path) -> None:
    plain = _fit(tmp_path / "a", [], shuffle=True)
    precise = _fit(tmp_path / "b", [PreciseBatchNorm(num_batches=3)], shuffle=True)
    for (name, a), b in zip(plain.named_parameters(), precise.parameters(), strict=True):
        assert torch.equal(a, b), name  # the same batches and draws: the random state was restored
    bn_plain, bn_precise = plain.body[1], precise.body[1]
    assert not torch.allclose(bn_plain.running_mean, bn_precise.running_mean)

    # without shuffling, the last validation's statistics are the plain average over the first 3 training batches at
    # the final weights: each sample's input is scaled by 1 or 2 (its mask), so per channel the mean lies between
    # the means with every mask off and every mask on
    fixed = _fit(tmp_path / "c", [PreciseBatchNorm(num_batches=3)], shuffle=False)
    x = _Pairs().x[:24]
    with torch.no_grad():
        low, high = fixed.body[0](x).mean(0), fixed.body[0](2 * x).mean(0)
    mean = fixed.body[1].running_mean
    assert bool(((mean >= torch.minimum(low, high) - 1e-5) & (mean <= torch.maximum(low, high) + 1e-5)).all())
    assert int(fixed.body[1].num_batches_tracked) == 3 and fixed.body[1].momentum == pytest.approx(0.1)


def test_precise_batchnorm_needs_a_reconstruction_module(tmp_path) -> None:
    with pytest.raises(ValueError, match="num_batches must be >= 1"):
        PreciseBatchNorm(num_batches=0)
    net = L.LightningModule()
    with pytest.raises(TypeError, match="training_mask"):
        PreciseBatchNorm().setup(L.Trainer(logger=False), net, "fit")
