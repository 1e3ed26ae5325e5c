"""Recompute every BatchNorm's running statistics of a trained network from training batches ("precise BN").

BatchNorm normalises with its batch's statistics in training and with running averages (momentum 0.1, so mostly the
last ~10 batches') in validation and test. When the features a layer sees drift during training, or differ between
training and test (the paper's fusion model adds the sum of 1-10 touches' embeddings to the visual features in
training and of exactly 10 in validation), a checkpoint's stored statistics need not be those of the inputs it is
scored on, and its validation error can jump while its training loss does not.

:func:`recalibrate_batchnorm` resets the statistics and recomputes them as the plain average over ``num_batches``
batches of the fixed weights (``momentum=None``, as ``torch.optim.swa_utils.update_bn`` does for averaged weights),
with the rest of the network in eval mode and no gradient. ``eval.py bn_recalibrate_batches=K`` applies it to each
checkpoint before scoring it; comparing the two scores tells a statistics mismatch from a worse network.
:class:`PreciseBatchNorm` (beyond the paper; ``experiment=full_precise_bn``) does it in training, before every
validation, so that the validation error that chooses the checkpoint, and the statistics the checkpoint keeps, are
those of its own weights. Training itself is unchanged: it normalises with batch statistics, and the random state is
restored after the recalibration's draws.
"""

from __future__ import annotations

import logging
import random
from collections.abc import Callable, Iterable
from itertools import chain, islice
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities import move_data_to_device
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

__all__ = [
    "PreciseBatchNorm",
    "batchnorm_statistics",
    "recalibrate_batchnorm",
    "recalibrate_module",
    "statistics_shift",
    "worst_layers",
]

log = logging.getLogger(__name__)

_NONE = object()


def batchnorm_statistics(model: nn.Module) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """A copy of every BatchNorm's running (mean, var), (C,) float each, by module name."""
    return {
        name: (m.running_mean.detach().clone(), m.running_var.detach().clone())
        for name, m in model.named_modules()
        if isinstance(m, _BatchNorm) and m.track_running_stats and m.running_mean is not None
    }


def statistics_shift(
    stored: dict[str, tuple[torch.Tensor, torch.Tensor]],
    data: dict[str, tuple[torch.Tensor, torch.Tensor]],
    depth: int | None = 2,
    eps: float = 1e-5,
) -> dict[str, dict[str, float]]:
    """How wrong eval-mode BatchNorm outputs are with the ``stored`` statistics when the inputs follow ``data``'s, per
    group of layers (the first ``depth`` parts of a name, e.g. ``net.visual``; None: each layer on its own).

    A layer normalises ``(x - mean_stored) / std_stored``; on inputs of mean ``mean_data`` and spread ``std_data`` the
    result has mean ``(mean_data - mean_stored) / std_stored`` (should be 0) and spread ``std_data / std_stored``
    (should be 1), before the layer's scale and shift. Returned per group: ``mean_shift``, the largest of the first
    over the group's channels; ``std_ratio``, the largest of the second and its inverse; ``layers``.
    """
    groups: dict[str, dict[str, float]] = {}
    for name, (mean_d, var_d) in data.items():
        if name not in stored:
            continue
        mean_s, var_s = stored[name]
        std_s, std_d = (var_s + eps).sqrt(), (var_d + eps).sqrt()
        shift = float(((mean_d - mean_s).abs() / std_s).max())
        ratio = float(torch.maximum(std_d / std_s, std_s / std_d).max())
        key = name if depth is None else ".".join(name.split(".")[:depth])
        g = groups.setdefault(key, {"layers": 0, "mean_shift": 0.0, "std_ratio": 1.0})
        g["layers"] += 1
        g["mean_shift"] = max(g["mean_shift"], shift)
        g["std_ratio"] = max(g["std_ratio"], ratio)
    return groups


def recalibrate_batchnorm(
    model: nn.Module,
    batches: Iterable[Any],
    forward: Callable[[Any], object],
    num_batches: int,
) -> int:
    """Replace the running mean / variance of every BatchNorm under ``model`` by their average over batches.

    Args:
        model: the trained network (its weights are not changed).
        batches: training batches, e.g. a train dataloader (moved to the device by ``forward``).
        forward: runs the network on one batch (e.g. ``lambda b: module(b, mask)``); its output is discarded.
        num_batches: how many batches to average over (>= 1).

    Returns:
        The number of BatchNorm layers recalibrated (0: none in ``model``; nothing is run then).

    Raises:
        ValueError: ``num_batches`` < 1, or ``batches`` holds none.
    """
    if int(num_batches) < 1:
        raise ValueError(f"recalibrate_batchnorm: num_batches must be >= 1, got {num_batches}")
    norms = [m for m in model.modules() if isinstance(m, _BatchNorm) and m.track_running_stats]
    if not norms:
        log.info("recalibrate_batchnorm: %s has no BatchNorm with running statistics", type(model).__name__)
        return 0
    stream = iter(batches)
    first = next(stream, _NONE)
    if first is _NONE:
        raise ValueError("recalibrate_batchnorm: the batches given are empty (nothing was changed)")
    was_training = model.training
    momenta = [m.momentum for m in norms]
    model.eval()
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average over the batches, not an exponential one
        m.train()
    seen = 0
    try:
        with torch.no_grad():
            for batch in chain([first], islice(stream, int(num_batches) - 1)):
                forward(batch)
                seen += 1
    finally:
        for m, momentum in zip(norms, momenta, strict=True):
            m.momentum = momentum
        model.train(was_training)
    log.info("recalibrated %d BatchNorm layers over %d batches", len(norms), seen)
    return len(norms)


def worst_layers(
    stored: dict[str, tuple[torch.Tensor, torch.Tensor]],
    data: dict[str, tuple[torch.Tensor, torch.Tensor]],
    n: int = 5,
) -> list[dict[str, float | str]]:
    """The ``n`` layers whose eval-mode output :func:`statistics_shift` finds furthest off (by the larger of the mean
    shift and the spread ratio), furthest first: ``[{"layer", "mean_shift", "std_ratio"}, ...]`` (a list, so that the
    order survives a JSON writer that sorts keys)."""
    per_layer = statistics_shift(stored, data, depth=None)
    ranked = sorted(per_layer.items(), key=lambda kv: -max(kv[1]["mean_shift"], kv[1]["std_ratio"]))
    return [{"layer": name, "mean_shift": g["mean_shift"], "std_ratio": g["std_ratio"]} for name, g in ranked[:n]]


def recalibrate_module(
    module: L.LightningModule,
    batches: Iterable[Any],
    num_batches: int,
    mask: Callable[[Any], torch.Tensor | None],
) -> int:
    """:func:`recalibrate_batchnorm` for a reconstruction module: each batch moved to the module's device and run as
    ``module(batch, mask(batch))`` (``mask``: e.g. ``module.training_mask``). Returns the layers recalibrated."""
    device = module.device

    def forward(batch: Any) -> object:
        batch = move_data_to_device(batch, device)
        return module(batch, mask(batch))

    return recalibrate_batchnorm(module, batches, forward, num_batches)


class PreciseBatchNorm(L.Callback):
    """Before every validation of a fit, recompute the BatchNorm statistics over ``num_batches`` training batches
    (:func:`recalibrate_batchnorm`), with the touches a training step reads (the module's ``training_mask``).

    The sanity check before training is left alone. The random state (Python's, NumPy's and torch's: the touch counts
    drawn, the loader's shuffle) is saved and restored around it, so the training batches and touch counts after it
    are those of a fit without it. Cost: ``num_batches`` forward passes per validation (20 of the 82 training
    batches of ``paper_cpu``: about 6% of an epoch on the CPU).

    Args:
        num_batches: training batches to average over (>= 1).
    """

    def __init__(self, num_batches: int = 20) -> None:
        super().__init__()
        if int(num_batches) < 1:
            raise ValueError(f"PreciseBatchNorm: num_batches must be >= 1, got {num_batches}")
        self.num_batches = int(num_batches)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if getattr(pl_module, "training_mask", None) is None:
            raise TypeError(
                f"PreciseBatchNorm needs a module with training_mask(batch) (the reconstruction module); "
                f"{type(pl_module).__name__} has none: remove callbacks.precise_bn"
            )

    def on_validation_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.state.fn != "fit":
            return
        loader = trainer.datamodule.train_dataloader() if trainer.datamodule is not None else trainer.train_dataloader
        states = (random.getstate(), np.random.get_state(), torch.get_rng_state())
        cuda_states = torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None
        try:
            recalibrate_module(pl_module, loader, self.num_batches, pl_module.training_mask)
        finally:
            random.setstate(states[0])
            np.random.set_state(states[1])
            torch.set_rng_state(states[2])
            if cuda_states is not None:
                torch.cuda.set_rng_state_all(cuda_states)
