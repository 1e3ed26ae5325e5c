"""Stop training at the first non-finite loss, naming the step, the loss terms and what to change.

Without this check a diverging run (``model.optimizer.lr=1e6``) trains on NaN weights to the end and reports the
NaN as its result, or stops much later on an unrelated error inside the metrics ("invalid multinomial
distribution"). Both LightningModules call :func:`check_finite_loss` in ``training_step``.
"""

from __future__ import annotations

from collections.abc import Mapping

import lightning as L
import torch
from torch import Tensor

__all__ = ["NonFiniteLossError", "check_finite_loss"]


class NonFiniteLossError(RuntimeError):
    """The training loss became NaN or infinite (the run diverged)."""


def _value(v: Tensor | float) -> str:
    x = float(v.detach().float().mean()) if isinstance(v, Tensor) else float(v)
    return f"{x:.4g}"


def _learning_rate(module: L.LightningModule) -> float | None:
    try:
        return float(module.trainer.optimizers[0].param_groups[0]["lr"])
    except (RuntimeError, AttributeError, IndexError, KeyError, TypeError):  # no trainer attached, no optimizer
        return None


def check_finite_loss(module: L.LightningModule, terms: Mapping[str, Tensor], key: str = "loss") -> None:
    """Raise :class:`NonFiniteLossError` if ``terms[key]`` (a scalar tensor) is NaN or infinite.

    Args:
        module: the LightningModule whose ``training_step`` computed ``terms`` (for the epoch, step and lr).
        terms: every named loss term of the step, ``key`` among them; all are named in the message.
    Raises:
        NonFiniteLossError: naming the epoch, the global step, every term's value and the hint (lower the
            learning rate, check the batch); the checkpoints written so far are kept.
    """
    loss = terms[key]
    if bool(torch.isfinite(loss.detach()).all()):
        return
    try:
        epoch, step = module.current_epoch, module.global_step
    except RuntimeError:  # not attached to a trainer
        epoch, step = None, None
    where = f" at epoch {epoch}, step {step}" if step is not None else ""
    values = ", ".join(f"{k}={_value(v)}" for k, v in terms.items())
    lr = _learning_rate(module)
    lr_text = f" (now {lr:g})" if lr is not None else ""
    raise NonFiniteLossError(
        f"training loss is {_value(loss)}{where} (terms: {values}): the run diverged. Lower the learning rate"
        f"{lr_text}, e.g. model.optimizer.lr 10x smaller, or check this batch's inputs for NaN; the checkpoints "
        f"written so far are kept"
    )
