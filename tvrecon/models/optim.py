"""Optimizer and scheduler wiring shared by the LightningModules (Hydra gives ``_partial_`` factories)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
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


def lr_scaled_groups(
    named_parameters: Iterable[tuple[str, nn.Parameter]],
    optimizer_factory: Callable[..., Any],
    lr_scales: Mapping[str, float],
) -> list[dict[str, Any]]:
    """Parameter groups where parameters under a name prefix train with ``lr * scale``.

    Args:
        named_parameters: ``module.named_parameters()``.
        optimizer_factory: the ``partial`` optimizer; its ``lr`` keyword is the base learning rate.
        lr_scales: name prefix (e.g. ``"net.fusion"``) -> factor; the longest matching prefix wins.

    Returns:
        Groups for the optimizer: one without ``lr`` (the base) and one per prefix with ``lr`` set.

    Raises:
        ValueError: the factory has no ``lr`` keyword, a factor is not positive, or a prefix matches no parameter.
    """
    base = getattr(optimizer_factory, "keywords", {}).get("lr")
    if base is None:
        raise ValueError("lr_scales needs the optimizer's base lr as a keyword (optimizer.lr in the model config)")
    for prefix, scale in lr_scales.items():
        if not float(scale) > 0:
            raise ValueError(f"lr_scales[{prefix!r}] must be > 0, got {scale}")
    prefixes = sorted(lr_scales, key=len, reverse=True)
    groups: dict[str | None, list[nn.Parameter]] = {None: [], **{p: [] for p in prefixes}}
    for name, param in named_parameters:
        if not param.requires_grad:
            continue
        match = next((p for p in prefixes if name == p or name.startswith(p + ".")), None)
        groups[match].append(param)
    empty = [p for p in prefixes if not groups[p]]
    if empty:
        raise ValueError(f"lr_scales prefixes {empty} match no trainable parameter (names look like 'net.fusion.aggs')")
    out: list[dict[str, Any]] = [{"params": groups[None]}] if groups[None] else []
    out += [{"params": groups[p], "lr": float(base) * float(lr_scales[p])} for p in prefixes]
    return out
