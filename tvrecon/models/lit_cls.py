"""LightningModule of the N-touch tactile classifier (paper section 4.2, Table 2).

Which touches a sample shows is decided by the dataset (:mod:`tvrecon.data.touches.select`, the one owner of that
choice): the training split draws N of the object's cached touches afresh at every epoch, in random order (the
paper: "during each training iteration, we randomly choose N tactile images"), validation and test serve a fixed
subset. This module keeps the first ``num_touches`` valid touches it is given (a uniform random subset in training,
since the draw is in random order) and draws nothing itself; at every ``on_train_epoch_start`` it passes the epoch
to the training datasets (:func:`~tvrecon.data.touches.select.set_loader_epoch`). The network sees the touches
stacked as ``(B, N, 3, h, w)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import lightning as L
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.data.touches.select import set_loader_epoch
from tvrecon.models.class_names import datamodule_class_names
from tvrecon.models.finite_loss import check_finite_loss
from tvrecon.models.heading_ensemble import check_headings, heading_ensemble
from tvrecon.models.optim import configure_optimizers
from tvrecon.utils.shape_check import check_shape

__all__ = ["ClassificationModule", "gather_touches", "other_object_index", "select_touches", "touch_index"]


def touch_index(touch_mask: Tensor, n: int, generator: torch.Generator | None = None, random: bool = False) -> Tensor:
    """Indices of ``n`` valid touches per sample.

    Args:
        touch_mask: (B, T) bool, True for real touches.
        n: touches to keep per sample, 1 <= n <= T.
        generator: RNG for ``random=True``.
        random: draw the touches uniformly among the valid ones (training) instead of taking the first n.

    Returns:
        (B, n) int64 indices into T.
    """
    check_shape(touch_mask, "(B, T)", "touch_mask")
    B, T = touch_mask.shape
    if not 1 <= n <= T:
        raise ValueError(f"n must be in [1, T={T}], got {n}")
    valid = touch_mask.sum(1)
    if bool((valid < n).any()):
        raise ValueError(
            f"every sample needs at least {n} valid touches, got as few as {int(valid.min())}: generate more touches "
            f"per object (data touches_per_object) or lower model.num_touches"
        )
    if random:
        score = torch.rand(B, T, generator=generator, device="cpu").to(touch_mask.device)
    else:
        score = torch.arange(T, dtype=torch.float32, device=touch_mask.device).expand(B, T)
    score = score.masked_fill(~touch_mask, float("inf"))
    return score.argsort(dim=1)[:, :n]


def gather_touches(x: Tensor, idx: Tensor) -> Tensor:
    """Args: x (B, T, ...) per-touch tensor; idx (B, n) int64. Returns (B, n, ...): x[b, idx[b]]."""
    return x[torch.arange(x.shape[0], device=x.device)[:, None], idx.to(x.device)]


def select_touches(
    tactile: Tensor, touch_mask: Tensor, n: int, generator: torch.Generator | None = None, random: bool = False
) -> Tensor:
    """Pick ``n`` valid touches per sample (:func:`touch_index`).

    Args:
        tactile: (B, T, 3, h, w) float tactile images, padded.
        touch_mask: (B, T) bool, True for real touches.
        n, generator, random: see :func:`touch_index`.

    Returns:
        (B, n, 3, h, w) float.
    """
    check_shape(tactile, "(B, T, 3, h, w)", "tactile")
    B, T = tactile.shape[:2]
    if touch_mask.shape != (B, T):
        raise ValueError(f"touch_mask must have shape (B, T) = {(B, T)}, got {tuple(touch_mask.shape)}")
    return gather_touches(tactile, touch_index(touch_mask, n, generator, random))


def other_object_index(labels: Tensor) -> tuple[Tensor, Tensor]:
    """For every sample, the next sample of the batch (cyclically) whose label differs: another object's touches.

    Args:
        labels: (B,) int64 class labels.

    Returns:
        idx (B,) int64 partner indices and valid (B,) bool (False where every other sample has the same label; the
        partner is then the sample itself and must not be counted).
    """
    B = labels.shape[0]
    own = torch.arange(B, device=labels.device)
    if B < 2:
        return own, torch.zeros(B, dtype=torch.bool, device=labels.device)
    cand = (own[:, None] + torch.arange(1, B, device=labels.device)[None]) % B  # (B, B-1)
    differs = labels[cand] != labels[:, None]  # (B, B-1)
    valid = differs.any(1)
    first = differs.to(torch.int8).argmax(1)  # the first differing candidate (0 where none)
    return torch.where(valid, cand[own, first], own), valid


class ClassificationModule(L.LightningModule):
    """Cross-entropy training of a tactile classifier over N touches.

    Args:
        net: built classifier, ``forward(*inputs) -> logits (B, num_classes)`` where ``inputs`` are the batch's
            per-touch tensors named by ``net.touch_inputs`` (default ``("tactile",)``: tactile (B, N, 3, h, w)), each
            (B, N, ...) with the same N touches.
        optimizer: partial optimizer (``_partial_: true``), called with the parameters.
        scheduler: partial LR scheduler called with the optimizer, or None.
        num_touches: N touches per training sample (the paper trains one model per N; Table 2 sweeps
            ``model.num_touches=1,2,4,6,8,10 seed=0,1,2``). The data must provide at least N valid touches.
        touch_sampling: ``"fixed"`` trains with exactly N touches and tests with N only (paper protocol);
            ``"random"`` trains with n ~ U{1..N} touches per batch (the rest masked out) and tests every count
            of ``eval_touches`` up to N, so one model fills a whole Table 2 row.
        eval_touches: touch counts evaluated at test time with ``touch_sampling="random"``.
        name: experiment name for the result dict and tables.
        seed: run seed, recorded in the result dict (Table 2 averages over seeds).
        class_names: label -> class name for the per-class results; None reads ``datamodule.library.classes`` at
            test time (labels beyond the names are called ``class<i>``).
        controls: test-time touch controls: ``"other"`` also classifies every test sample from another object's
            touches (the next sample of the batch with another label, :func:`other_object_index`) and scores the
            prediction against the sample's own label: a model that reads its touches falls towards chance.
        headings: validation and test ask the network K times, the touch set turned about +z by ``2 pi k / K``, and
            average the class probabilities (:mod:`tvrecon.models.heading_ensemble`; for a network that reads 3D
            inputs and trained with ``data.rotate_pose``). 1 (default): the set as it is, one answer.

    Test results (``test_results``, written to ``metrics.json``): ``accuracy`` {k: fraction}, and per touch count k
    the ``confusion`` matrix (C, C) int (rows: true class, columns: predicted), ``per_class`` accuracy {name:
    fraction} of the classes present in the test split, and ``classes`` (the C names); with the ``"other"`` control
    ``accuracy_other`` {k: fraction over the samples that had a partner}.
    """

    def __init__(
        self,
        net: nn.Module,
        optimizer: Callable[..., torch.optim.Optimizer],
        scheduler: Callable[..., Any] | None = None,
        num_touches: int = 1,
        touch_sampling: str = "fixed",
        eval_touches: Sequence[int] | None = None,
        name: str = "classify",
        seed: int | None = None,
        class_names: Sequence[str] | None = None,
        controls: Sequence[str] = (),
        headings: int = 1,
    ) -> None:
        super().__init__()
        # the network and the optimizer/scheduler factories stay out of the checkpoint's hparams: checkpoints then hold
        # plain data only and load with torch.load(weights_only=True); the model is rebuilt from the run's config
        self.save_hyperparameters(logger=False, ignore=["net", "optimizer", "scheduler"])
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        self.net = net
        if touch_sampling not in ("fixed", "random"):
            raise ValueError(f"touch_sampling must be 'fixed' or 'random', got {touch_sampling!r}")
        limit = getattr(net, "num_touches", None)
        if num_touches < 1 or (limit is not None and int(num_touches) > int(limit)):
            raise ValueError(f"num_touches must be in [1, {limit}] (the classifier's maximum), got {num_touches}")
        self.num_touches = int(num_touches)
        self.touch_sampling = touch_sampling
        if touch_sampling == "fixed" or eval_touches is None:
            self.eval_touches = [self.num_touches]
        else:
            self.eval_touches = sorted({int(k) for k in eval_touches if 1 <= int(k) <= self.num_touches})
        self.class_names = None if class_names is None else [str(c) for c in class_names]
        self.controls = [str(c) for c in controls]
        unknown = sorted(set(self.controls) - {"other"})
        if unknown:
            raise ValueError(f"unknown classification controls {unknown}; available: ['other']")
        self.touch_inputs = tuple(getattr(net, "touch_inputs", ("tactile",)))
        self.headings = check_headings(headings, self.touch_inputs)
        self._confusion: dict[int, Tensor] = {}
        self._other: dict[int, Tensor] = {}
        self.test_results: dict[str, Any] | None = None

    def forward(self, *inputs: Tensor) -> Tensor:
        """Args: the per-touch inputs named by ``touch_inputs``, each (B, N, ...). Returns logits (B, C) float."""
        return self.net(*inputs)

    def evaluate(self, *inputs: Tensor) -> Tensor:
        """The evaluation answer: logits (B, C) float with ``headings=1``, else the log of the class probabilities
        averaged over the headings (:func:`~tvrecon.models.heading_ensemble.heading_ensemble`); argmax is the class."""
        if self.headings == 1:
            return self(*inputs)
        return heading_ensemble(self, inputs, self.touch_inputs, self.headings)

    def _inputs(self, batch: dict[str, Tensor], n: int) -> list[Tensor]:
        """The first ``n`` valid touches of every input the network reads, each (B, n, ...)."""
        missing = [key for key in self.touch_inputs if key not in batch]
        if missing:
            raise KeyError(
                f"the classifier reads {list(self.touch_inputs)} per touch but the batch has no {missing}"
                + (": set data.patches=true" if any(key.startswith("patch_") for key in missing) else "")
            )
        check_shape(batch["tactile"], "(B, T, 3, h, w)", "tactile")
        idx = touch_index(batch["touch_mask"], n)
        return [gather_touches(batch[key], idx) for key in self.touch_inputs]

    def on_train_epoch_start(self) -> None:
        """Give the training datasets the epoch of their touch draw (before Lightning builds the epoch's iterator)."""
        set_loader_epoch(self.trainer.train_dataloader, self.current_epoch)

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        inputs = self._inputs(batch, self.num_touches)
        if self.touch_sampling == "random":
            n = int(torch.randint(1, self.num_touches + 1, ()))
            inputs = [x[:, :n] for x in inputs]
        logits = self(*inputs)
        loss = F.cross_entropy(logits, batch["label"])
        acc = (logits.argmax(1) == batch["label"]).float().mean()
        check_finite_loss(self, {"loss": loss, "acc": acc})  # a diverged run stops here, naming the step and lr
        B = logits.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=B)
        self.log("train/acc", acc, prog_bar=True, batch_size=B)
        return loss

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        logits = self.evaluate(*self._inputs(batch, self.num_touches))
        B = logits.shape[0]
        self.log("val/loss", F.cross_entropy(logits, batch["label"]), prog_bar=True, batch_size=B, sync_dist=True)
        acc = (logits.argmax(1) == batch["label"]).float().mean()
        self.log("val/acc", acc, prog_bar=True, batch_size=B, sync_dist=True)

    def _names(self, num_classes: int) -> list[str]:
        names = self.class_names if self.class_names is not None else datamodule_class_names(self.trainer)
        return [names[i] if i < len(names) else f"class{i}" for i in range(num_classes)]

    def on_test_epoch_start(self) -> None:
        self._confusion = {}
        self._other = {}

    def test_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        available = int(batch["touch_mask"].sum(1).min())
        for k in self.eval_touches:
            if k > available:
                continue
            inputs = self._inputs(batch, k)
            logits = self.evaluate(*inputs)  # (B, C)
            C = logits.shape[1]
            pair = batch["label"] * C + logits.argmax(1)  # (B,) true * C + predicted
            counts = torch.bincount(pair, minlength=C * C).view(C, C)
            self._confusion[k] = counts if k not in self._confusion else self._confusion[k] + counts
            if "other" in self.controls:
                partner, valid = other_object_index(batch["label"])
                hits = (self.evaluate(*[x[partner] for x in inputs]).argmax(1) == batch["label"]) & valid
                tally = torch.stack([hits.sum(), valid.sum()])  # (2,) correct, counted
                self._other[k] = tally if k not in self._other else self._other[k] + tally

    def on_test_epoch_end(self) -> None:
        names: list[str] = []
        accuracy: dict[str, float] = {}
        confusion: dict[str, list[list[int]]] = {}
        per_class: dict[str, dict[str, float]] = {}
        for k in self.eval_touches:
            if k not in self._confusion:
                continue
            matrix = self.trainer.strategy.reduce(self._confusion[k], reduce_op="sum").cpu()  # (C, C)
            names = self._names(matrix.shape[0])
            total = int(matrix.sum())
            accuracy[str(k)] = float(matrix.diagonal().sum()) / total
            self.log(f"test/acc@{k}", accuracy[str(k)], sync_dist=False)
            confusion[str(k)] = matrix.tolist()
            rows = matrix.sum(1)
            per_class[str(k)] = {
                names[c]: float(matrix[c, c]) / float(rows[c]) for c in range(len(names)) if int(rows[c]) > 0
            }
        accuracy_other: dict[str, float] = {}
        for k, tally in sorted(self._other.items()):
            hits, total = (int(v) for v in self.trainer.strategy.reduce(tally, reduce_op="sum").cpu())
            if total > 0:
                accuracy_other[str(k)] = hits / total
                self.log(f"test/acc_other@{k}", accuracy_other[str(k)], sync_dist=False)
        self.test_results = {
            "task": "classification",
            "name": self.hparams.name,
            "seed": self.hparams.seed,
            "num_touches": self.num_touches,
            "headings": self.headings,
            "accuracy": accuracy,
            "per_class": per_class,
            "confusion": confusion,
            "classes": names,
        }
        if accuracy_other:
            self.test_results["accuracy_other"] = accuracy_other

    def configure_optimizers(self) -> Any:
        trainable = [p for p in self.trainer.model.parameters() if p.requires_grad]  # freeze= leaves some out
        return configure_optimizers(trainable, self.optimizer_factory, self.scheduler_factory)
