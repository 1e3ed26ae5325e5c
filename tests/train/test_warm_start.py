"""Warm starts (``init_from``) and frozen parts (``freeze``): what is loaded, what stays fixed, and clear refusals."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch
from torch import nn
from torch.utils.data import DataLoader, TensorDataset

from tvrecon.train.warm_start import FreezeParameters, load_initial_weights
from tvrecon.utils.checkpoint import CorruptCheckpointError


class _Net(L.LightningModule):
    """A body (conv + BatchNorm) and a head; ``extra`` adds a part the other kind of net lacks."""

    def __init__(self, width: int = 4, extra: bool = False) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(1, width, 3, padding=1), nn.BatchNorm2d(width), nn.ReLU())
        self.head = nn.Linear(width, 2)
        self.extra = nn.Linear(2, 2) if extra else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.head(self.body(x).mean(dim=(2, 3)))
        return y if self.extra is None else self.extra(y)

    def training_step(self, batch: list[torch.Tensor], batch_idx: int) -> torch.Tensor:
        x, t = batch
        return nn.functional.cross_entropy(self(x), t)

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD([p for p in self.parameters() if p.requires_grad], lr=0.5)


def _save(model: nn.Module, path: Path) -> Path:
    torch.save({"state_dict": model.state_dict()}, path)
    return path


def test_shared_entries_are_loaded_and_the_rest_listed(tmp_path: Path) -> None:
    torch.manual_seed(0)
    source = _Net()
    ckpt = _save(source, tmp_path / "a.ckpt")
    target = _Net(extra=True)
    extra_before = target.extra.weight.detach().clone()
    report = load_initial_weights(target, ckpt)
    assert all(torch.equal(v, target.state_dict()[k]) for k, v in source.state_dict().items())
    assert torch.equal(target.extra.weight, extra_before)  # not in the checkpoint: its own initialisation
    assert sorted(report.missing) == ["extra.bias", "extra.weight"] and report.unexpected == []
    assert "body.1.running_mean" in report.loaded  # buffers (BatchNorm statistics) come too

    back = load_initial_weights(_Net(), _save(target, tmp_path / "b.ckpt"))
    assert sorted(back.unexpected) == ["extra.bias", "extra.weight"] and back.missing == []


def test_another_size_another_model_or_a_broken_file_is_refused(tmp_path: Path) -> None:
    wide = _save(_Net(width=8), tmp_path / "wide.ckpt")
    with pytest.raises(ValueError, match=r"another shape.*body\.0\.weight \(8, 1, 3, 3\) vs \(4, 1, 3, 3\)"):
        load_initial_weights(_Net(), wide)

    other = _save(nn.Sequential(nn.Linear(3, 3)), tmp_path / "other.ckpt")
    with pytest.raises(ValueError, match="shares no parameter name.*another kind of model"):
        load_initial_weights(_Net(), other)

    broken = tmp_path / "broken.ckpt"
    broken.write_bytes(wide.read_bytes()[:200])
    with pytest.raises(CorruptCheckpointError, match="broken.ckpt is truncated or corrupt"):
        load_initial_weights(_Net(), broken)


def _fit(model: L.LightningModule, callbacks: list[L.Callback], tmp_path: Path) -> None:
    g = torch.Generator().manual_seed(0)
    data = TensorDataset(torch.randn(16, 1, 6, 6, generator=g), torch.randint(0, 2, (16,), generator=g))
    trainer = L.Trainer(
        max_epochs=2,
        callbacks=callbacks,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    trainer.fit(model, DataLoader(data, batch_size=4))


class _BodyMode(L.Callback):
    """Records whether the body was in train mode at each training step (Lightning puts the model in train mode)."""

    def __init__(self) -> None:
        self.training: list[bool] = []

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, *args: object) -> None:
        self.training.append(pl_module.body.training)


def test_frozen_parts_keep_weights_and_batchnorm_statistics_while_the_rest_trains(tmp_path: Path) -> None:
    torch.manual_seed(0)
    model = _Net()
    body = {k: v.detach().clone() for k, v in model.body.state_dict().items()}
    head = model.head.weight.detach().clone()
    mode = _BodyMode()
    _fit(model, [FreezeParameters(["body"]), mode], tmp_path)
    assert len(mode.training) == 8 and not any(mode.training)  # eval mode: the checkpoint's statistics normalise
    assert all(torch.equal(v, model.body.state_dict()[k]) for k, v in body.items())  # running stats included
    assert not torch.equal(model.head.weight, head)
    assert not any(p.requires_grad for p in model.body.parameters())

    control = _Net()  # the same fit without the callback moves the body and its statistics
    running = control.body[1].running_mean.clone()
    mode = _BodyMode()
    _fit(control, [mode], tmp_path)
    assert not torch.equal(control.body[1].running_mean, running) and all(mode.training)


def test_freezing_a_module_the_model_lacks_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\['trunk'\] name no module of the model"):
        _fit(_Net(), [FreezeParameters(["trunk"])], tmp_path)
    with pytest.raises(ValueError, match="at least one module"):
        FreezeParameters([])
