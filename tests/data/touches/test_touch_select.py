"""Which cached touches a sample uses: a fresh draw per training epoch, a fixed subset at evaluation."""

from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from torch import Tensor, nn

from tvrecon.data.datamodule import ClassificationDataModule
from tvrecon.data.shapes import ObjectLibrary
from tvrecon.data.task_datasets import EvalDraws, TactileClassificationDataset
from tvrecon.data.touches.select import TouchSelector, set_loader_epoch
from tvrecon.models.lit_cls import ClassificationModule

# tiny simulation (about 1 s for the 2 objects x 5 touches): 8x8 pad, 3 layers, 32^3 grid
SIM = {
    "sensor": {"resolution": (8, 8), "layers": 3},
    "press": {"n_grid": 32, "max_depth": 1.5, "gap": 0.5, "speed_fraction": 0.2},
    "touch": {"strengths": [{"threshold": 0.05}], "cone_deg": 10.0},
    "tactile_size": 8,
}
CLASSES = ["cube", "torus"]
M, N = 5, 2
_LIB = ObjectLibrary()


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("touch_select_cache")


def dataset(cache: Path, **over) -> TactileClassificationDataset:
    args = dict(num_objects=2, classes=CLASSES, touches_per_object=M, num_touches=N, cache_dir=cache, library=_LIB)
    args.update(SIM)
    args.update(over)
    return TactileClassificationDataset(**args)


# ---------------------------------------------------------------------------------------------- the selector
def test_training_draws_new_touches_each_epoch() -> None:
    sel = TouchSelector(num_cached=10, num_touches=2, redraw=True)
    seen = set()
    for epoch in range(20):
        idx = sel.indices(12345, epoch)
        assert len(set(idx.tolist())) == 2 and idx.min() >= 0 and idx.max() < 10
        seen.update(idx.tolist())
    assert len(seen) > 2
    np.testing.assert_array_equal(sel.indices(12345, 7), sel.indices(12345, 7))  # reproducible
    draws = [[sel.indices(item, e).tolist() for e in range(5)] for item in (12345, 54321)]
    assert draws[0] != draws[1]  # depends on the item


def test_evaluation_is_deterministic_and_keeps_the_legacy_subset() -> None:
    sel = TouchSelector(num_cached=10, num_touches=4, redraw=False)
    first = sel.indices(777, 0)
    for epoch in range(20):
        np.testing.assert_array_equal(sel.indices(777, epoch), first)
    # the subset the dataset used before the selector existed: evaluation results stay comparable
    legacy = np.sort(np.random.default_rng(777).choice(10, size=4, replace=False))
    np.testing.assert_array_equal(first, legacy)
    k, mirror = sel.orientations(777, 3)
    assert k.tolist() == [0] * 4 and mirror.tolist() == [False] * 4


def test_orientations_are_seeded_and_cover_the_eight_poses() -> None:
    sel = TouchSelector(num_cached=10, num_touches=10, redraw=True)
    poses = set()
    for epoch in range(10):
        k, mirror = sel.orientations(5, epoch)
        assert k.shape == (10,) and mirror.dtype == bool
        poses.update(zip(k.tolist(), mirror.tolist(), strict=True))
    assert poses == {(k, m) for k in range(4) for m in (False, True)}
    np.testing.assert_array_equal(sel.orientations(5, 2)[0], sel.orientations(5, 2)[0])


def test_evaluation_draws_are_windows_that_show_every_touch_equally_often() -> None:
    one = TouchSelector(num_cached=10, num_touches=1, redraw=False, eval_draws=10)
    assert sorted(int(one.indices(99, 0, j)[0]) for j in range(10)) == list(range(10))  # N=1: every touch once
    four = TouchSelector(num_cached=10, num_touches=4, redraw=False, eval_draws=10)
    windows = [four.indices(99, 3, j) for j in range(10)]
    assert all(len(set(w.tolist())) == 4 for w in windows)
    assert len({tuple(w.tolist()) for w in windows}) == 10  # 10 different draws
    np.testing.assert_array_equal(np.bincount(np.concatenate(windows), minlength=10), np.full(10, 4))
    np.testing.assert_array_equal(four.indices(99, 0, 5), four.indices(99, 17, 5))  # no epoch term
    assert four.draws == 10 and TouchSelector(10, 4, redraw=True, eval_draws=10).draws == 1
    with pytest.raises(ValueError, match="draw must be in"):
        four.indices(99, 0, 10)
    with pytest.raises(ValueError, match="eval_draws <= num_cached"):
        TouchSelector(num_cached=10, num_touches=4, redraw=False, eval_draws=11)


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="num_touches <= num_cached"):
        TouchSelector(num_cached=3, num_touches=4, redraw=True)
    with pytest.raises(ValueError, match="num_cached must be >= 1"):
        TouchSelector(num_cached=0, num_touches=0, redraw=True)
    with pytest.raises(ValueError, match="epoch must be >= 0"):
        TouchSelector(num_cached=3, num_touches=1, redraw=True).indices(1, -1)
    with pytest.raises(ValueError, match="epoch must be >= 0"):
        set_loader_epoch(None, -2)


# ---------------------------------------------------------------------------------------------- the dataset
def test_item_shows_more_than_n_touches_in_training_and_the_same_at_test(cache: Path) -> None:
    train, test = dataset(cache, redraw_touches=True), dataset(cache)
    seen: set[bytes] = set()
    test_first = test[1]["tactile"]
    for epoch in range(20):
        train.set_epoch(epoch)
        test.set_epoch(epoch)
        sample = train[1]
        assert sample["tactile"].shape == (N, 3, 8, 8)
        seen.update(t.numpy().tobytes() for t in sample["tactile"])
        assert torch.equal(test[1]["tactile"], test_first)
    assert len(seen) > N
    raw, _ = train.raw(1)
    train.set_epoch(4)
    sel = train.touch_indices(1)
    assert torch.equal(train[1]["positions"], torch.from_numpy(raw["positions"][sel]))


def test_eval_draws_serve_each_object_k_times_through_the_test_loader(cache: Path) -> None:
    kwargs = dict(
        train={"num_objects": 2, "classes": CLASSES},
        test={"num_objects": 2, "classes": CLASSES},
        cache_dir=cache,
        touches_per_object=M,
        num_touches=1,
        **SIM,
    )
    plain = ClassificationDataModule(**kwargs).test_dataloader()
    drawn = ClassificationDataModule(eval_draws=M, **kwargs).test_dataloader()
    assert len(plain.dataset) == 2 and len(drawn.dataset) == 2 * M
    base = drawn.dataset.dataset
    raw, _ = base.raw(1)
    shown = torch.stack([drawn.dataset[M + j]["tactile"][0] for j in range(M)])  # object 1's five draws
    expected = base._tactile(raw["tactile"])  # all M cached touches of object 1
    order = [int(base.touch_indices(1, draw=j)[0]) for j in range(M)]
    assert sorted(order) == list(range(M)) and torch.equal(shown, expected[order])
    assert {int(drawn.dataset[i]["label"]) for i in range(M)} == {int(plain.dataset[0]["label"])}
    assert not isinstance(ClassificationDataModule(eval_draws=M, **kwargs).train_dataloader().dataset, EvalDraws)
    with pytest.raises(IndexError, match="out of range"):
        drawn.dataset[2 * M]


def test_rotation_augmentation_only_turns_the_training_draw(cache: Path) -> None:
    plain, turned = dataset(cache, redraw_touches=True), dataset(cache, redraw_touches=True, rotate_touches=True)
    evaluation = dataset(cache, rotate_touches=True)  # no redraw: augmentation has no effect
    changed = False
    for epoch in range(3):
        plain.set_epoch(epoch)
        turned.set_epoch(epoch)
        a, b = plain[0], turned[0]
        assert torch.equal(a["positions"], b["positions"])  # the same touches, only turned
        assert torch.allclose(a["tactile"].abs().sum((1, 2, 3)), b["tactile"].abs().sum((1, 2, 3)))
        changed |= not torch.equal(a["tactile"], b["tactile"])
    assert changed
    assert torch.equal(evaluation[0]["tactile"], dataset(cache)[0]["tactile"])
    with pytest.raises(ValueError, match="square"):
        dataset(cache, rotate_touches=True, tactile_size=(8, 6))


# ---------------------------------------------------------------------------------------------- the training loop
class _MeanNet(nn.Module):
    """Smallest classifier with the TactileClassifier interface: (B, N, 3, h, w) -> (B, C)."""

    num_touches = N

    def __init__(self) -> None:
        super().__init__()
        self.fc = nn.Linear(3, len(_LIB.classes))

    def forward(self, x: Tensor) -> Tensor:
        return self.fc(x.mean(dim=(1, 3, 4)))


class _Record(L.Callback):
    """Positions of the touches of every training batch, per epoch and label."""

    def __init__(self) -> None:
        self.seen: dict[int, dict[int, Tensor]] = {}

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        per_label = self.seen.setdefault(trainer.current_epoch, {})
        for label, pos in zip(batch["label"].tolist(), batch["positions"], strict=True):
            per_label[label] = pos.clone()


@pytest.mark.parametrize("num_workers", [0, 1])
def test_datamodule_train_loader_changes_touches_between_epochs(cache: Path, num_workers: int) -> None:
    dm = ClassificationDataModule(
        train={"num_objects": 2, "classes": CLASSES},
        test={"num_objects": 2, "classes": CLASSES},
        batch_size=2,
        num_workers=num_workers,
        cache_dir=cache,
        touches_per_object=M,
        num_touches=N,
        **SIM,
    )
    model = ClassificationModule(_MeanNet(), lambda params: torch.optim.SGD(params, lr=0.0), num_touches=N)
    record = _Record()
    trainer = L.Trainer(
        max_epochs=4,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        callbacks=[record],
    )
    trainer.fit(model, datamodule=dm)
    train = dm.datasets["train"]
    assert train.redraw_touches and not dm.make_dataset("test").redraw_touches
    draws = set()
    for epoch in range(4):
        for index in range(2):
            raw, _ = train.raw(index)
            expected = torch.from_numpy(raw["positions"][train.touch_indices(index, epoch)])
            assert torch.equal(record.seen[epoch][train.label_of(index)], expected), (epoch, index)
            draws.add((index, tuple(train.touch_indices(index, epoch).tolist())))
    assert len(draws) > 2  # the touches changed between epochs (not one fixed draw per item)


def test_persistent_workers_with_a_per_epoch_draw_raise(cache: Path) -> None:
    kwargs = dict(train={"num_objects": 2, "classes": CLASSES}, cache_dir=cache, touches_per_object=M, **SIM)
    dm = ClassificationDataModule(num_workers=1, persistent_workers=True, **kwargs)
    with pytest.raises(ValueError, match="persistent_workers"):
        dm.train_dataloader()
    fixed = ClassificationDataModule(
        num_workers=1,
        persistent_workers=True,
        **{**kwargs, "train": {"num_objects": 2, "classes": CLASSES, "redraw_touches": False}},
    )
    assert not fixed.train_dataloader().dataset.redraw_touches


def test_pose_turn_is_one_seeded_yaw_per_training_draw(cache: Path) -> None:
    """rotate_pose turns positions, directions and contact patches of a training draw by one angle about +z (the
    touches' relative geometry and heights kept); the patches are those of the cached touches; evaluation is not
    turned."""
    from tvrecon.data.pose_augment import turn_about_up

    plain = dataset(cache, redraw_touches=True, patches=True)
    turned = dataset(cache, redraw_touches=True, patches=True, rotate_pose=True)
    for epoch in range(2):
        plain.set_epoch(epoch)
        turned.set_epoch(epoch)
        a, b = plain[0], turned[0]
        angle = turned.selector.yaw(turned.seeds(0)[3], epoch)
        assert 0.0 <= angle < 2 * np.pi
        for key in ("positions", "directions", "patch_points", "patch_normals"):
            torch.testing.assert_close(b[key], turn_about_up(a[key], angle))
        assert torch.equal(a["patch_mask"], b["patch_mask"]) and torch.equal(a["tactile"], b["tactile"])
        assert a["patch_mask"].any(1).all()  # every touch has contact points
        d = a["positions"][:, None] - a["positions"][None]
        torch.testing.assert_close((b["positions"][:, None] - b["positions"][None]).norm(dim=-1), d.norm(dim=-1))
    assert plain.selector.yaw(7, 0) != plain.selector.yaw(7, 1)  # a new heading every epoch
    evaluation = dataset(cache, patches=True, rotate_pose=True)
    torch.testing.assert_close(evaluation[0]["patch_points"], dataset(cache, patches=True)[0]["patch_points"])
    assert evaluation.selector.yaw(7, 3) == 0.0
    # the patches are the cached touches' contact patches (the image augmentation does not move them)
    spun = dataset(cache, redraw_touches=True, patches=True, rotate_touches=True)
    plain.set_epoch(0)
    assert not torch.equal(spun[0]["tactile"], plain[0]["tactile"])
    torch.testing.assert_close(spun[0]["patch_points"], plain[0]["patch_points"])
