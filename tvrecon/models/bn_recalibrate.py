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
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from itertools import chain, islice
from typing import Any

import torch
from torch import nn
from torch.nn.modules.batchnorm import _BatchNorm

__all__ = ["recalibrate_batchnorm"]

log = logging.getLogger(__name__)

_NONE = object()


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
