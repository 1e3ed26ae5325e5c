"""GradNormMonitor logs the gradient norm that clipping acts on: before clipping, equal to clip_grad_norm_'s."""

from __future__ import annotations

import lightning as L
import pytest
import torch
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from tvrecon.train.grad_norm import GradNormMonitor, total_grad_norm


class _Linear(L.LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.layer = nn.Linear(4, 1)
        self.seen: list[float] = []

    def training_step(self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int) -> torch.Tensor:
        x, y = batch
        return ((self.layer(x) - y) ** 2).mean() * 100.0

    def on_before_optimizer_step(self, optimizer: torch.optim.Optimizer) -> None:
        # Lightning calls the callbacks' hook first, then this one, both before clipping
        self.seen.append(float(torch.nn.utils.get_total_norm([p.grad for p in self.parameters()])))

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=1e-3)


def test_total_grad_norm_matches_clip_grad_norm() -> None:
    torch.manual_seed(0)
    params = [nn.Parameter(torch.randn(3, 4)), nn.Parameter(torch.randn(5)), nn.Parameter(torch.randn(2))]
    for p in params[:2]:
        p.grad = torch.randn_like(p)
    expected = torch.nn.utils.clip_grad_norm_(params, max_norm=1e9)
    assert torch.allclose(total_grad_norm(params), expected)
    assert float(total_grad_norm([nn.Parameter(torch.ones(2))])) == 0.0  # no gradient anywhere


def test_logged_norm_is_the_unclipped_one(tmp_path) -> None:
    torch.manual_seed(0)
    data = TensorDataset(torch.randn(32, 4), torch.randn(32, 1) * 10)
    module = _Linear()
    logged: list[float] = []
    window: list[float] = []

    class _Record(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:  # noqa: ANN001
            logged.append(float(trainer.callback_metrics["train/grad_norm"]))
            window.append(float(trainer.callback_metrics["train/grad_norm_max"]))

    trainer = L.Trainer(
        max_steps=4,
        log_every_n_steps=2,
        gradient_clip_val=1e-3,  # far below the norms: clipping acts on every step
        callbacks=[GradNormMonitor(), _Record()],
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        default_root_dir=tmp_path,
    )
    trainer.fit(module, DataLoader(data, batch_size=8))
    assert len(logged) == 4
    assert logged == pytest.approx(module.seen, rel=1e-6)
    assert min(logged) > 1e-2  # the norm before clipping, not the clipped 1e-3
    # the window's largest norm restarts after every 2nd step (the steps the logger keeps)
    assert window == pytest.approx([logged[0], max(logged[:2]), logged[2], max(logged[2:4])], rel=1e-6)


def test_bad_norm_type_is_refused() -> None:
    with pytest.raises(ValueError, match="norm_type"):
        GradNormMonitor(norm_type=0)
