"""Lightning datamodules of the generated datasets, built from ``configs/data/*.yaml``.

Both datamodules take the dataset settings shared by all splits at the top level (seed, cache, sensor / press /
touch configs, tactile resolution) and one mapping per split (``train``, ``val``, ``test``) with at least the split
size and optionally ``classes``, ``split`` (object split of the library, default the split's own name),
``instance_offset``, ``seed`` and any dataset argument to override for that split. The library's ``train``, ``val``
and ``test`` objects never share a shape seed, so validation and test objects are never seen in training.

Batches come from the default collate: reconstruction ``tactile (B,T,3,h,w)``, ``touch_mask (B,T)`` with
T = ``max_touches`` (padded), classification ``tactile (B,N,3,h,w)``, ``touch_mask (B,N)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from lightning import LightningDataModule
from torch.utils.data import DataLoader, Dataset

from tvrecon.data.cache.housekeeping import announce_uncached, remove_stale_tmp
from tvrecon.data.dataset_base import GeneratedDataset
from tvrecon.data.shapes import ObjectLibrary
from tvrecon.data.task_datasets import EvalDraws, ReconstructionDataset, TactileClassificationDataset
from tvrecon.data.touches.policies import resize_tactile
from tvrecon.utils.config_utils import check_whole

__all__ = ["ReconstructionDataModule", "ClassificationDataModule", "device_resize", "worker_init"]

_SPLITS = ("train", "val", "test")


def worker_init(worker_id: int) -> None:
    """Dataloader worker init: one torch thread per worker (the workers already run in parallel)."""
    torch.set_num_threads(1)


def _plain(value: Any) -> Any:
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(value, DictConfig | ListConfig):
            return OmegaConf.to_container(value, resolve=True)
    except ImportError:  # pragma: no cover
        pass
    return value


class _GeneratedDataModule(LightningDataModule):
    dataset_cls: type[GeneratedDataset] = GeneratedDataset
    size_key = "num_items"

    def __init__(
        self,
        train: Mapping[str, Any],
        val: Mapping[str, Any] | None = None,
        test: Mapping[str, Any] | None = None,
        batch_size: int = 4,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        persistent_workers: bool = False,
        pin_memory: bool = False,
        pregenerate: bool = False,
        pregenerate_workers: int | None = None,
        library: ObjectLibrary | Mapping[str, Any] | None = None,
        cache_dir: str | Path | None = None,
        seed: int = 0,
        device_tactile_size: int | None = None,
        **dataset_kwargs: Any,
    ) -> None:
        super().__init__()
        check_whole(batch_size, "data.batch_size", minimum=1)  # 2.5 was silently 2
        check_whole(num_workers, "data.num_workers", minimum=0)
        if eval_batch_size is not None:
            check_whole(eval_batch_size, "data.eval_batch_size", minimum=1)
        if pregenerate_workers is not None:
            check_whole(pregenerate_workers, "data.pregenerate_workers", minimum=1)
        self.splits: dict[str, dict[str, Any] | None] = {
            "train": dict(_plain(train)),
            "val": dict(_plain(val)) if val else None,
            "test": dict(_plain(test)) if test else None,
        }
        for name, split in self.splits.items():
            if split is not None and self.size_key not in split:
                raise ValueError(f"data split {name!r} needs {self.size_key!r} (its size), got keys {sorted(split)}")
            if split is not None:
                check_whole(split[self.size_key], f"data.{name}.{self.size_key}", minimum=1)
        self.batch_size = int(batch_size)
        self.eval_batch_size = int(eval_batch_size) if eval_batch_size else self.batch_size
        self.num_workers = int(num_workers)
        self.persistent_workers = bool(persistent_workers) and self.num_workers > 0
        self.pin_memory = bool(pin_memory)
        self.pregenerate = bool(pregenerate)
        self.pregenerate_workers = pregenerate_workers
        library = _plain(library)
        self.library = library if isinstance(library, ObjectLibrary) else ObjectLibrary(**(library or {}))
        self.cache_dir = None if cache_dir is None else str(cache_dir)
        self.seed = int(seed)
        self.dataset_kwargs = {k: _plain(v) for k, v in dataset_kwargs.items()}
        if device_tactile_size is not None:
            check_whole(device_tactile_size, "data.device_tactile_size", minimum=1)
        self.device_tactile_size = None if device_tactile_size is None else int(device_tactile_size)
        self.datasets: dict[str, GeneratedDataset] = {}

    # ------------------------------------------------------------------ datasets
    def _split_args(self, name: str) -> dict[str, Any]:
        split = self.splits.get(name)
        if split is None:
            raise ValueError(f"this datamodule has no {name!r} split configured")
        args: dict[str, Any] = {"split": name, "seed": self.seed}  # the library keeps the three splits disjoint
        args.update(self.dataset_kwargs)
        args.update(split)
        return args

    def make_dataset(self, name: str, **overrides: Any) -> GeneratedDataset:
        """Build the dataset of split ``name`` (``train``/``val``/``test``) with optional argument overrides.

        E.g. ``dm.make_dataset("test", num_touches=5)`` for evaluation with a fixed number of touches: load-time
        options like this reuse the cache of the full split.
        """
        args = self._split_args(name)
        args.update(overrides)
        return self.dataset_cls(library=self.library, cache_dir=self.cache_dir, **args)

    def available_splits(self) -> list[str]:
        return [n for n in _SPLITS if self.splits.get(n) is not None]

    def prepare_data(self) -> None:
        """Pre-generate every configured split into the cache when ``pregenerate`` is set (rank 0 only)."""
        if not self.pregenerate:
            return
        from tvrecon.data.generation.pool import pregenerate_splits

        sets = {name: self.make_dataset(name) for name in self.available_splits()}
        pregenerate_splits(sets, workers=self.pregenerate_workers)  # one pool of workers for every split

    def setup(self, stage: str | None = None) -> None:
        wanted = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",), "predict": ("test",)}
        names = wanted.get(stage, _SPLITS) if stage else _SPLITS
        if not self.datasets:  # the job's first setup: the leftovers of killed runs go first
            remove_stale_tmp(self.cache_dir)
        for name in names:
            if self.splits.get(name) is not None and name not in self.datasets:
                self.datasets[name] = self.make_dataset(name)
                missing = announce_uncached(name, self.datasets[name])  # the first epoch on an empty cache says so
                plan = getattr(self.datasets[name], "plan_compile", None)
                if missing and plan is not None:  # compile="auto": the touches each loading process simulates
                    per_item = int(getattr(self.datasets[name], "touches_per_item", 1))
                    plan(missing * per_item // max(1, self.num_workers))

    def _loader(self, name: str, shuffle: bool) -> DataLoader:
        if name not in self.datasets:
            self.setup(None)
        if name not in self.datasets:
            raise ValueError(f"this datamodule has no {name!r} split configured")
        return DataLoader(
            self._served(name),
            batch_size=self.batch_size if name == "train" else self.eval_batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            persistent_workers=self.persistent_workers,
            pin_memory=self.pin_memory,
            worker_init_fn=worker_init if self.num_workers > 0 else None,
            generator=torch.Generator().manual_seed(self.seed) if shuffle else None,
        )

    def _served(self, name: str) -> Dataset:
        """The dataset a split's loader serves (a subclass may wrap the split's dataset)."""
        return self.datasets[name]

    def on_after_batch_transfer(self, batch: Any, dataloader_idx: int) -> Any:
        """With ``device_tactile_size`` S, resize the batch's tactile (B,T,3,h,w) -> (B,T,3,S,S) where the batch
        now is (the GPU): the loaders then collate and copy the small load-time images (``tactile_size``, e.g. the
        pad's own 31 pixels) instead of the model's 224, which on a GPU leaves the host the bottleneck."""
        return device_resize(batch, self.device_tactile_size)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)


def device_resize(batch: Any, size: int | None) -> Any:
    """``batch`` with its ``tactile`` (B,T,3,h,w) resized to (B,T,3,size,size) by :func:`resize_tactile`, the
    load-time resize moved after the transfer (same kornia bilinear resize; zeros of padded touches stay zeros).
    ``size`` None or a batch without tactile images: ``batch`` as it is."""
    if size is None or not isinstance(batch, Mapping) or "tactile" not in batch:
        return batch
    tactile = batch["tactile"]
    if tactile.ndim != 5:
        raise ValueError(f"device_tactile_size needs a batch tactile of shape (B,T,3,h,w), got {tuple(tactile.shape)}")
    out = resize_tactile(tactile.flatten(0, 1), size)  # (B*T,3,S,S); (0,3,S,S) when there is no touch
    return {**batch, "tactile": out.unflatten(0, tactile.shape[:2])}


class ReconstructionDataModule(_GeneratedDataModule):
    """Datamodule of :class:`~tvrecon.data.task_datasets.ReconstructionDataset` splits.

    Split mappings need ``num_samples``. Shared dataset arguments (``min_touches``, ``max_touches``,
    ``num_touches``, ``num_points``, ``tactile_size``, ``tactile_scale``, ``sensor``, ``press``, ``touch``,
    ``render``) are given at the top level and can be overridden per split.

    Batch: image (B,3,H,W), K (B,3,3), RT (B,3,4), tactile (B,T,3,h,w), positions (B,T,3), directions (B,T,3),
    touch_mask (B,T) bool, points (B,N,3), normals (B,N,3), label (B,) int64 with T = max_touches.
    """

    dataset_cls = ReconstructionDataset
    size_key = "num_samples"


class ClassificationDataModule(_GeneratedDataModule):
    """Datamodule of :class:`~tvrecon.data.task_datasets.TactileClassificationDataset` splits.

    Split mappings need ``num_objects``; ``touches_per_object`` and ``num_touches`` (N) are shared arguments.
    Batch: tactile (B,N,3,h,w), touch_mask (B,N) bool, positions (B,N,3), directions (B,N,3), label (B,) int64.

    The ``train`` split draws its N touches afresh every epoch (``redraw_touches`` defaults to True there and to
    False in ``val`` / ``test``; a split mapping may set it), see :mod:`tvrecon.data.touches.select`. The epoch reaches
    the dataset from :meth:`~tvrecon.models.lit_cls.ClassificationModule.on_train_epoch_start`, which needs workers
    re-created every epoch: ``persistent_workers=True`` with a redrawing train split raises ValueError.
    ``rotate_touches`` (shared, default False) turns on the orientation augmentation of the training draws;
    ``eval_draws`` (shared, default 1) K > 1 tests and validates every object with K fixed draws of N touches;
    ``patches`` (shared) adds patch_points (B,N,Q,3), patch_normals (B,N,Q,3) and patch_mask (B,N,Q) to the batch and
    ``rotate_pose`` turns each training sample's touch set about +z (see the dataset).
    """

    dataset_cls = TactileClassificationDataset
    size_key = "num_objects"

    def _split_args(self, name: str) -> dict[str, Any]:
        args = super()._split_args(name)
        if "redraw_touches" not in (self.splits.get(name) or {}) and "redraw_touches" not in self.dataset_kwargs:
            args["redraw_touches"] = name == "train"
        return args

    def train_dataloader(self) -> DataLoader:
        if "train" not in self.datasets:
            self.setup(None)
        if self.persistent_workers and getattr(self.datasets.get("train"), "redraw_touches", False):
            raise ValueError(
                "persistent_workers=True keeps the dataset copy of the first epoch in the workers, so the training "
                "split would show the same touches every epoch: set data.persistent_workers=false (workers are then "
                "re-created each epoch and see the new epoch's draw) or data.train.redraw_touches=false"
            )
        return super().train_dataloader()

    def _served(self, name: str) -> Dataset:
        """Evaluation splits with ``eval_draws`` K > 1 serve every object K times
        (:class:`~tvrecon.data.task_datasets.EvalDraws`); otherwise the split's dataset."""
        dataset = self.datasets[name]
        if dataset.redraw_touches or dataset.selector.draws == 1:
            return dataset
        return EvalDraws(dataset)

    @property
    def num_touches(self) -> int:
        return int(self.dataset_kwargs.get("num_touches", 1))

    @property
    def num_classes(self) -> int:
        return len(self.library.classes)
