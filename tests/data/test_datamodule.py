"""Datamodules built from configs/data/*.yaml: batches of the documented shapes, splits, presets vs Table 1."""

from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from tiny_press import TINY_PRESS

from tvrecon.data.datamodule import ClassificationDataModule, ReconstructionDataModule
from tvrecon.data.presets import TABLE1, SplitSize, compose_preset, preset_names, split_sizes

# shrink the tiny presets further so a batch generates in a few seconds
FAST = [
    *TINY_PRESS,
    "tactile_size=12",
]
RECON_FAST = FAST + ["train.num_samples=2", "val.num_samples=1", "test.num_samples=2", "max_touches=4"]
RECON_FAST += ["render.image_size=32", "num_points=50"]


def _dm(preset: str, cache: Path, overrides: list[str]):
    cfg = compose_preset(preset, [f"cache_dir={cache}"] + overrides)
    return instantiate(cfg, _convert_="all")


def test_every_preset_composes_and_instantiates(tmp_path: Path):
    names = preset_names()
    assert {"tiny", "small", "paper", "cls_tiny", "cls_small", "cls_paper", "cls_paper_cpu"} <= set(names)
    for name in names:
        dm = _dm(name, tmp_path, [])
        assert isinstance(dm, ReconstructionDataModule | ClassificationDataModule)
        assert dm.available_splits() == ["train", "val", "test"]
        for split in dm.available_splits():  # builds datasets (cheap: nothing is generated)
            assert len(dm.make_dataset(split)) > 0
    assert not list(tmp_path.rglob("*.npz"))


def test_paper_presets_match_table1():
    recon = split_sizes(compose_preset("paper"))
    assert recon["train"] == TABLE1["reconstruction"]["train"] == SplitSize(35, 6500, 650)
    assert recon["test"] == TABLE1["reconstruction"]["test"] == SplitSize(10, 500, 50)
    cls = split_sizes(compose_preset("cls_paper"))
    assert cls["train"] == TABLE1["classification"]["train"] == SplitSize(35, 5500, 0)
    assert cls["test"] == TABLE1["classification"]["test"] == SplitSize(35, 1500, 0)
    small = split_sizes(compose_preset("small"))
    assert small["train"].classes == 10 and small["train"].tactile < 2000


def test_cls_paper_cpu_has_table1_sizes_and_many_objects_per_class():
    """The CPU classification preset: Table 1's image counts, a validation split, 15-16 train and 4-5
    test objects of every class (none shared between splits), tactile maps at the pad's resolution, the paper's
    touches."""
    cfg = compose_preset("cls_paper_cpu", ["cache_dir=null"])
    sizes = split_sizes(cfg)
    assert sizes["train"] == TABLE1["classification"]["train"] == SplitSize(35, 5500, 0)
    assert sizes["test"] == TABLE1["classification"]["test"] == SplitSize(35, 1500, 0)
    assert sizes["val"] == SplitSize(35, 700, 0)
    assert [cfg.tactile_size] * 2 == list(cfg.sensor.resolution) == [31, 31]  # no upsampling of the pad
    assert cfg.touch._target_.endswith("PaperSweepTouchPolicy")  # the paper's touches
    dm = instantiate(cfg, _convert_="all")
    per_class = {}
    for split, (lo, hi) in {"train": (15, 16), "val": (2, 2), "test": (4, 5)}.items():
        ds = dm.make_dataset(split)
        objects = [ds.object_of(i) for i in range(len(ds))]
        counts = {c: sum(o[0] == c for o in objects) for c in ds.library.classes}
        assert len(counts) == 35 and lo == min(counts.values()) and max(counts.values()) == hi, (split, counts)
        per_class[split] = {(c, ds.library.params(c, k, split)["seed"]) for c, k in objects}
    assert not per_class["train"] & per_class["test"] and not per_class["train"] & per_class["val"]


def test_paper_cpu_has_table1_reconstruction_sizes():
    """The CPU reconstruction preset at Table 1's size: train on all 35 classes (650 views, 6,500 tactile
    images), test on the 10 reconstruction classes (50 / 500), small's pad, grid and views, the paper's touches; the
    checkpoint is chosen on validation objects of the 10 test classes, none shared with train or test."""
    cfg = compose_preset("paper_cpu", ["cache_dir=null"])
    sizes = split_sizes(cfg)
    assert sizes["train"] == TABLE1["reconstruction"]["train"] == SplitSize(35, 6500, 650)
    assert sizes["test"] == TABLE1["reconstruction"]["test"] == SplitSize(10, 500, 50)
    assert sizes["val"] == SplitSize(10, 200, 20)
    small = compose_preset("small", ["cache_dir=null"])
    for block in ("sensor", "press", "touch", "render"):  # small's geometry, only the split sizes differ
        assert cfg[block] == small[block], block
    assert cfg.tactile_size == small.tactile_size and cfg.touch._target_.endswith("PaperSweepTouchPolicy")
    dm = instantiate(cfg, _convert_="all")
    seen = {}
    for split in ("train", "val", "test"):
        ds = dm.make_dataset(split)
        objects = [ds.object_of(i) for i in range(len(ds))]
        seen[split] = {(c, ds.library.params(c, k, split)["seed"]) for c, k in objects}
    assert len({c for c, _ in seen["train"]}) == 35 and len({c for c, _ in seen["test"]}) == 10
    assert not seen["train"] & seen["test"] and not seen["train"] & seen["val"] and not seen["val"] & seen["test"]


def test_reconstruction_batches_have_documented_shapes(tmp_path: Path):
    dm = _dm("tiny", tmp_path, RECON_FAST)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    B, T = 2, 4
    assert batch["image"].shape == (B, 3, 32, 32)
    assert batch["K"].shape == (B, 3, 3) and batch["RT"].shape == (B, 3, 4)
    assert batch["tactile"].shape == (B, T, 3, 12, 12)
    assert batch["positions"].shape == (B, T, 3) and batch["directions"].shape == (B, T, 3)
    assert batch["touch_mask"].shape == (B, T) and batch["touch_mask"].dtype == torch.bool
    assert batch["points"].shape == (B, 50, 3) and batch["normals"].shape == (B, 50, 3)
    assert batch["label"].shape == (B,) and batch["label"].dtype == torch.int64
    assert batch["touch_mask"][:, 0].all()  # at least one touch, padding at the end
    # train, val and test objects are disjoint
    train, val, test = dm.datasets["train"], dm.datasets["val"], dm.make_dataset("test")

    def seeds(ds):
        return {ds.spec(i)["mesh"]["seed"] for i in range(len(ds))}

    assert (train.split, val.split, test.split) == ("train", "val", "test")
    assert not seeds(train) & seeds(val) and not seeds(train) & seeds(test)
    # eval with a fixed number of touches reuses the same cache entries
    fixed = dm.make_dataset("train", num_touches=2)
    assert all(fixed.is_cached(i) for i in range(len(fixed)))
    assert fixed[0]["touch_mask"].tolist() == [True, True, False, False]


def test_worker_processes_give_the_same_batches(tmp_path: Path):
    dm0 = _dm("tiny", tmp_path / "a", RECON_FAST + ["batch_size=2"])
    dm1 = _dm("tiny", tmp_path / "b", RECON_FAST + ["batch_size=2", "num_workers=1"])
    dm0.setup("fit")
    dm1.setup("fit")
    b0 = next(iter(dm0.train_dataloader()))
    b1 = next(iter(dm1.train_dataloader()))  # generated in a worker process
    for k in b0:
        assert torch.equal(b0[k], b1[k]), k


def test_classification_batches(tmp_path: Path):
    over = FAST + ["train.num_objects=2", "touches_per_object=3", "num_touches=3", "batch_size=2"]
    dm = _dm("cls_tiny", tmp_path, over)
    assert dm.num_touches == 3 and dm.num_classes == 35
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["tactile"].shape == (2, 3, 3, 12, 12)
    assert batch["touch_mask"].shape == (2, 3) and batch["touch_mask"].all()
    assert batch["label"].shape == (2,) and batch["label"].dtype == torch.int64


def test_prepare_data_pregenerates(tmp_path: Path):
    over = FAST + ["train.num_objects=2", "val.num_objects=1", "test.num_objects=1", "touches_per_object=2"]
    dm = _dm("cls_tiny", tmp_path, over + ["pregenerate=true", "pregenerate_workers=1"])
    dm.prepare_data()
    assert len(list(tmp_path.rglob("*.npz"))) == 4


def test_bad_config_raises(tmp_path: Path):
    with pytest.raises(ValueError, match="needs 'num_samples'"):
        ReconstructionDataModule(train={"num_objects": 3}, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="batch_size"):
        ReconstructionDataModule(train={"num_samples": 3}, batch_size=0)
    dm = ReconstructionDataModule(train={"num_samples": 3})
    with pytest.raises(ValueError, match="no 'test' split"):
        dm.make_dataset("test")
