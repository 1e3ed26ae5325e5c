"""Optimizer and scheduler wiring shared by the LightningModules (Hydra gives ``_partial_`` factories)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from torch import nn


def configure_optimizers(
    parameters: Iterable[nn.Parameter],
    optimizer_factory: Callable[..., Any],
    scheduler_factory: Callable[..., Any] | None,
) -> dict[str, Any]:
    """Lightning's ``configure_optimizers`` result: the optimizer, plus a per-epoch scheduler when one is configured.

    Args:
        parameters: the parameters to optimize.
        optimizer_factory: ``partial(torch.optim.X, lr=...)`` taking ``params=``.
        scheduler_factory: ``partial(torch.optim.lr_scheduler.Y, ...)`` taking ``optimizer=``, or None.
    """
    optimizer = optimizer_factory(params=parameters)
    if scheduler_factory is None:
        return {"optimizer": optimizer}
    scheduler = scheduler_factory(optimizer=optimizer)
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"}}
