"""Log the total gradient norm of every optimizer step, before any clipping (``train/grad_norm``).

A validation curve that jumps while the training loss does not (the paper's ``full`` on ``paper_cpu``: 15.2 -> 26.3
-> 13.3 between epochs 3 and 5, seed 44) is either an optimisation spike or a change the training loss does not see
(BatchNorm's running statistics, used in validation only). The logged norm tells the two apart and sizes a
``trainer.gradient_clip_val`` where clipping is tried. It lands in ``metrics.csv`` and ``loss_curves.png`` with the
loss terms.

Lightning calls ``on_before_optimizer_step`` after the backward pass (and AMP's unscaling) and before it clips the
gradients, so the norm is the one clipping acts on.
"""

from __future__ import annotations

import lightning as L
import torch
from torch.optim import Optimizer

__all__ = ["GradNormMonitor", "total_grad_norm"]


def total_grad_norm(parameters: object, norm_type: float = 2.0) -> torch.Tensor:
    """The norm of all gradients together, as ``torch.nn.utils.clip_grad_norm_`` computes it (0-dim float tensor;
    0 where no parameter has a gradient)."""
    grads = [p.grad.detach() for p in parameters if getattr(p, "grad", None) is not None]
    if not grads:
        return torch.zeros(())
    return torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g, norm_type) for g in grads]), norm_type)


class GradNormMonitor(L.Callback):
    """Log ``train/grad_norm`` (the total 2-norm of the gradients, before clipping) at every optimizer step, and
    ``train/grad_norm_max``, the largest since the last step the logger kept (one in ``log_every_n_steps``).

    Args:
        norm_type: the norm's order (2 = Euclidean, as ``gradient_clip_algorithm=norm`` uses).
    """

    def __init__(self, norm_type: float = 2.0) -> None:
        super().__init__()
        if not norm_type > 0:
            raise ValueError(f"GradNormMonitor: norm_type must be > 0, got {norm_type}")
        self.norm_type = float(norm_type)
        self._window_max = 0.0

    def on_before_optimizer_step(self, trainer: L.Trainer, pl_module: L.LightningModule, optimizer: Optimizer) -> None:
        params = [p for group in optimizer.param_groups for p in group["params"]]
        norm = total_grad_norm(params, self.norm_type)
        self._window_max = max(self._window_max, float(norm))
        # one value per step, not averaged over the epoch: batch_size only spares Lightning inferring one
        pl_module.log("train/grad_norm", norm, on_step=True, on_epoch=False, batch_size=1)
        # the logger keeps every log_every_n_steps-th step only: the largest norm since the last kept one shows a
        # spike between them
        pl_module.log("train/grad_norm_max", self._window_max, on_step=True, on_epoch=False, batch_size=1)
        every = max(1, int(getattr(trainer, "log_every_n_steps", 1) or 1))
        if (trainer.global_step + 1) % every == 0:
            self._window_max = 0.0
