"""One owner of which cached touches a sample uses (and, in training, in which pad orientation).

Every generated item caches M touches (:class:`~tvrecon.data.task_datasets.GeneratedDataset`). Which of them a sample
shows is decided here and nowhere else:

- **Classification** (:class:`~tvrecon.data.task_datasets.TactileClassificationDataset` through :class:`TouchSelector`):
  training draws N of the M touches afresh at every visit (paper section 4.2: "during each training iteration, we
  randomly choose N tactile images"), in random order, reproducibly from ``(item seed, epoch)`` where the item seed
  is the dataset's load seed of ``(seed, split, index)``; evaluation takes a fixed seeded subset, sorted, the same
  for every epoch, or with ``eval_draws = K > 1`` K fixed draws per object: the K windows of N consecutive touches
  of a seeded permutation of the M touches, so every cached touch is shown equally often (with K = M and N = 1 each
  test touch is classified once: the paper's 1,500 test tactile images of Table 1). The
  :class:`~tvrecon.models.lit_cls.ClassificationModule` keeps the first N touches it is given; it draws nothing.
- **Reconstruction**: the dataset serves the first T of the ``max_touches`` cached touches (T drawn per
  sample from its load seed, or fixed by ``num_touches``) and
  :class:`~tvrecon.models.lit_recon.ReconstructionModule` keeps the first k of those per training sample
  (:func:`~tvrecon.models.recon_batch.keep_first_touches`); the test modes keep the first 2 / 5 / 10. The first k
  touches are a random subset already (the touches of an item are drawn independently), so this is the paper's
  "1 to 10 tactile images per iteration" with a fixed set of touches per object.

The epoch reaches the dataset through :func:`set_loader_epoch` (called by the LightningModule at every
``on_train_epoch_start``). It works with ``num_workers=0`` (the dataset is read in the main process) and with
``num_workers > 0`` when ``persistent_workers=False``: Lightning creates the epoch's dataloader iterator (which
copies the dataset into fresh workers) after ``on_train_epoch_start``. Persistent workers keep the copy of the first
epoch, so the datamodule refuses ``persistent_workers=True`` with a per-epoch draw. One caveat: when a run resumes
from a checkpoint with workers, the first resumed epoch's iterator is built before the hook and repeats the draw of
epoch 0 once.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["TouchSelector", "set_loader_epoch"]

# SeedSequence stream tags of the training draws, orientations, evaluation windows and training yaws
_INDICES, _ORIENTATIONS, _EVAL, _YAW = 1, 2, 3, 4


@dataclass(frozen=True)
class TouchSelector:
    """Chooses the cached touch indices (and training orientations) of one sample.

    Args:
        num_cached: M, touches cached per item (>= 1).
        num_touches: N, touches per sample (1 <= N <= M).
        redraw: True (training): a fresh draw per ``epoch``; False (evaluation): the same sorted subset every epoch.
        eval_draws: K fixed draws per object at evaluation (1 <= K <= M; ignored when ``redraw``): 1 is the sorted
            seeded subset, K > 1 the first K windows of N consecutive touches (cyclically) of a seeded permutation.
    """

    num_cached: int
    num_touches: int
    redraw: bool
    eval_draws: int = 1

    def __post_init__(self) -> None:
        if int(self.num_cached) < 1:
            raise ValueError(f"num_cached must be >= 1, got {self.num_cached}")
        if not 1 <= int(self.num_touches) <= int(self.num_cached):
            raise ValueError(
                f"need 1 <= num_touches <= num_cached, got num_touches={self.num_touches}, num_cached={self.num_cached}"
            )
        if not 1 <= int(self.eval_draws) <= int(self.num_cached):
            raise ValueError(
                f"need 1 <= eval_draws <= num_cached (the windows repeat beyond M), got eval_draws={self.eval_draws}, "
                f"num_cached={self.num_cached}"
            )

    @staticmethod
    def _check(item_seed: int, epoch: int) -> None:
        if int(item_seed) < 0:
            raise ValueError(f"item_seed must be >= 0, got {item_seed}")
        if int(epoch) < 0:
            raise ValueError(f"epoch must be >= 0, got {epoch}")

    @property
    def draws(self) -> int:
        """Samples per item: ``eval_draws`` at evaluation, 1 in training (one fresh draw per epoch)."""
        return 1 if self.redraw else int(self.eval_draws)

    def indices(self, item_seed: int, epoch: int = 0, draw: int = 0) -> np.ndarray:
        """(N,) int64 distinct indices into the item's M cached touches.

        Training (``redraw``): a uniform draw of N touches in random order, a function of ``(item_seed, epoch)``.
        Evaluation, ``eval_draws == 1``: ``sort(default_rng(item_seed).choice(M, N, replace=False))``; ``eval_draws
        > 1``: draw ``j`` is ``perm[(j + arange(N)) % M]`` for a permutation ``perm`` seeded by ``item_seed`` (its
        order kept, as in training). ``epoch`` is ignored at evaluation.
        """
        self._check(item_seed, epoch)
        if not 0 <= int(draw) < self.draws:
            raise ValueError(f"draw must be in [0, {self.draws}), got {draw}")
        M, N = int(self.num_cached), int(self.num_touches)
        if not self.redraw and int(self.eval_draws) > 1:
            perm = np.random.default_rng(np.random.SeedSequence([int(item_seed), _EVAL])).permutation(M)
            return perm[(int(draw) + np.arange(N)) % M].astype(np.int64)
        if not self.redraw:
            rng = np.random.default_rng(int(item_seed))
            return np.sort(rng.choice(M, size=N, replace=False)).astype(np.int64)
        rng = np.random.default_rng(np.random.SeedSequence([int(item_seed), _INDICES, int(epoch)]))
        return rng.permutation(M)[:N].astype(np.int64)

    def orientations(self, item_seed: int, epoch: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Random pad orientations of the N touches for the training augmentation (one per touch, independent).

        Returns:
            k (N,) int64 in {0, 1, 2, 3} (quarter turns) and mirror (N,) bool, a function of ``(item_seed, epoch)``
            drawn from a stream separate from :meth:`indices` (turning augmentation on leaves the touches unchanged).
            Evaluation (``redraw=False``) always returns the identity (zeros, False).
        """
        self._check(item_seed, epoch)
        N = int(self.num_touches)
        if not self.redraw:
            return np.zeros(N, dtype=np.int64), np.zeros(N, dtype=bool)
        rng = np.random.default_rng(np.random.SeedSequence([int(item_seed), _ORIENTATIONS, int(epoch)]))
        code = rng.integers(0, 8, size=N)
        return (code % 4).astype(np.int64), code >= 4

    def yaw(self, item_seed: int, epoch: int = 0) -> float:
        """Random turn (radians, in [0, 2 pi)) of a training sample's whole touch set about the world's up axis (+z).

        For the pose augmentation (``rotate_pose``): one angle per sample, so the touches keep their relative
        geometry while the object's heading is unknown to the model. A function of ``(item_seed, epoch)`` from its
        own stream (turning it on changes no other draw); evaluation (``redraw=False``) returns 0.
        """
        self._check(item_seed, epoch)
        if not self.redraw:
            return 0.0
        rng = np.random.default_rng(np.random.SeedSequence([int(item_seed), _YAW, int(epoch)]))
        return float(rng.uniform(0.0, 2.0 * np.pi))


def _datasets(loaders: Any) -> Iterable[Any]:
    """Datasets of a dataloader or of a (nested) list / tuple / mapping of dataloaders."""
    if loaders is None:
        return []
    if isinstance(loaders, Mapping):
        return [d for v in loaders.values() for d in _datasets(v)]
    if isinstance(loaders, list | tuple):
        return [d for v in loaders for d in _datasets(v)]
    dataset = getattr(loaders, "dataset", None)
    return [] if dataset is None else [dataset]


def set_loader_epoch(loaders: Any, epoch: int) -> int:
    """Tell the datasets behind ``loaders`` the training epoch (for their per-epoch touch draw).

    Args:
        loaders: a DataLoader, or a list / tuple / mapping of them (e.g. ``trainer.train_dataloader``), or None.
        epoch: the epoch about to start (>= 0).
    Returns:
        the number of datasets that took the epoch (those with a ``set_epoch`` method).
    """
    if int(epoch) < 0:
        raise ValueError(f"epoch must be >= 0, got {epoch}")
    n = 0
    for dataset in _datasets(loaders):
        if callable(getattr(dataset, "set_epoch", None)):
            dataset.set_epoch(int(epoch))
            n += 1
    return n
