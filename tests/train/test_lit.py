"""LightningModules on synthetic batches: frame mapping, touch masking, fit/test loops and result dicts."""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import pytest
import torch
import trimesh
from synthetic import SyntheticClassificationDataModule, SyntheticReconDataModule

from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.models.components.fusion import TactileVisualFusion
from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.models.components.reconstructor import TactileVisualReconstructor
from tvrecon.models.lit_cls import ClassificationModule, other_object_index, select_touches
from tvrecon.models.lit_recon import ReconstructionModule
from tvrecon.models.recon_batch import gt_to_camera, keep_first_touches


def _net(mode: str = "fusion") -> TactileVisualReconstructor:
    chans = list(ResNet18Backbone.channels)
    fusion = None if mode == "visual_only" else TactileVisualFusion(chans, chans)
    tactile = None if mode == "visual_only" else ResNet18Backbone()
    return TactileVisualReconstructor(
        ResNet18Backbone(), tactile, fusion, MeshDeformer(chans, hidden=16, num_blocks=1), mode=mode
    )


def _optimizer(params):
    return torch.optim.AdamW(params, lr=1e-3)


def _trainer(tmp_path: Path, **kw) -> L.Trainer:
    base = dict(
        accelerator="cpu", devices=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        default_root_dir=str(tmp_path), enable_model_summary=False,
    )  # fmt: skip
    base.update(kw)
    return L.Trainer(**base)


def test_gt_to_camera_matches_manual_rotation() -> None:
    angle = 0.3
    R = torch.tensor([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])
    RT = torch.cat([R, torch.tensor([[0.1], [-0.2], [2.0]])], 1)[None].float()
    p = torch.randn(1, 5, 3)
    n = torch.nn.functional.normalize(torch.randn(1, 5, 3), dim=-1)
    pc, nc = gt_to_camera(p, n, RT)
    for i in range(5):
        assert torch.allclose(pc[0, i], R @ p[0, i] + RT[0, :, 3], atol=1e-5)
        assert torch.allclose(nc[0, i], R @ n[0, i], atol=1e-5)
    assert torch.allclose(nc.norm(dim=-1), torch.ones(1, 5), atol=1e-5)
    with pytest.raises(ValueError, match=r"RT must have shape \(B, 3, 4\)"):
        gt_to_camera(p, n, RT[:, :, :3])


def test_keep_first_touches_keeps_first_valid_ones() -> None:
    mask = torch.tensor([[True, False, True, True, False], [True, True, True, True, True]])
    assert keep_first_touches(mask, 2).tolist() == [
        [True, False, True, False, False],
        [True, True, False, False, False],
    ]
    assert not keep_first_touches(mask, 0).any()
    assert torch.equal(keep_first_touches(mask, 10), mask)
    with pytest.raises(ValueError, match=r"touch_mask must be a \(B, T\) bool tensor, got torch.int64"):
        keep_first_touches(mask.long(), 2)


def test_keep_first_touches_per_sample_counts() -> None:
    mask = torch.tensor([[True, False, True, True, False], [True, True, True, True, True]])
    assert keep_first_touches(mask, torch.tensor([1, 3])).tolist() == [
        [True, False, False, False, False],
        [True, True, True, False, False],
    ]
    assert torch.equal(keep_first_touches(mask, torch.tensor([2, 2])), keep_first_touches(mask, 2))
    with pytest.raises(ValueError, match=r"\(2,\) integer tensor"):
        keep_first_touches(mask, torch.tensor([1.0, 2.0]))
    with pytest.raises(ValueError, match="k must be >= 0"):
        keep_first_touches(mask, torch.tensor([1, -1]))


def test_select_touches_first_and_random() -> None:
    tactile = torch.arange(4.0)[None, :, None, None, None].expand(2, 4, 3, 2, 2).clone()
    mask = torch.tensor([[False, True, True, True], [True, True, False, True]])
    first = select_touches(tactile, mask, 2)
    assert first[:, :, 0, 0, 0].tolist() == [[1.0, 2.0], [0.0, 1.0]]
    rnd = select_touches(tactile, mask, 3, random=True)
    assert sorted(rnd[0, :, 0, 0, 0].tolist()) == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="at least 4 valid touches"):
        select_touches(tactile, mask, 4)


@pytest.mark.parametrize(
    ("mode", "expected"),
    [
        pytest.param("fusion", {"visual", "tv@2"}, marks=pytest.mark.slow),  # + 7 renders and 6 .obj exports
        ("visual_only", {"visual"}),
        ("tactile_only", {"tactile@2", "tactile@5"}),
    ],
)
def test_recon_fit_and_test_modes(tmp_path: Path, mode: str, expected: set[str]) -> None:
    export = mode == "fusion"  # renders cost ~1 s each: check the exports once
    model = ReconstructionModule(
        _net(mode), _optimizer, eval_touches=(2,) if export else (2, 5), metric_points=200, name=mode,
        loss_weights={"chamfer": 1.0, "normal": 1.6e-4, "edge": 0.1, "laplacian": 0.5, "move": 0.033},
        export=export, render_every_n_epochs=1 if export else 0,
    )  # fmt: skip
    dm = SyntheticReconDataModule(batch_size=2, n=4)
    trainer = _trainer(tmp_path, max_epochs=1, limit_train_batches=1, limit_val_batches=1, limit_test_batches=2)
    trainer.fit(model, dm)
    for key in ("train/loss", "train/chamfer", "train/laplacian", "val/chamfer", "val/loss"):
        assert key in trainer.callback_metrics and torch.isfinite(trainer.callback_metrics[key])
    trainer.test(model, dm)
    res = model.test_results
    assert res["task"] == "reconstruction" and res["name"] == mode
    assert set(res["modes"]) == expected
    for entry in res["modes"].values():
        assert entry["count"] == 4 and entry["chamfer"] > 0
        assert 0 <= entry["fscore@0.01"] <= entry["fscore@0.02"] <= 1
        assert set(entry["per_class"]) == {"bottle", "bowl", "can"}
        # the per-class means average back to the overall mean (weighted by class counts 2, 1, 1)
        pc = entry["per_class"]
        assert math.isclose((2 * pc["bottle"] + pc["bowl"] + pc["can"]) / 4, entry["chamfer"], rel_tol=1e-6)
    if export:
        # synthetic sample i has 1 + i % 10 valid touches: 1, 2, 3, 4 -> first-2 uses 1, 2, 2, 2 = 1.75 on average
        assert res["modes"]["tv@2"]["touches"] == pytest.approx(1.75)
        assert res["modes"]["visual"]["touches"] == 0
        assert (tmp_path / "renders" / "epoch_000.png").is_file()
        assert len(list((tmp_path / "meshes").glob("*.obj"))) == 3 * len(expected)
        assert len(list((tmp_path / "renders").glob("test_*.png"))) == 3 * len(expected)
        mesh = trimesh.load(tmp_path / "meshes" / "bottle_tv2.obj", process=False)
        assert len(mesh.vertices) == 2466 and len(mesh.faces) == 4928
    else:
        assert not (tmp_path / "meshes").exists() and not (tmp_path / "renders").exists()


def test_recon_random_touch_count_in_range() -> None:
    model = ReconstructionModule(_net(), _optimizer, min_touches=3, max_touches=4)
    counts = model._touch_counts(200)
    assert counts.shape == (200,) and set(counts.tolist()) == {3, 4}  # drawn per sample, both ends reached
    with pytest.raises(ValueError, match="min_touches <= max_touches"):
        ReconstructionModule(_net(), _optimizer, min_touches=5, max_touches=4)
    free = ReconstructionModule(_net(), _optimizer, min_touches=0, max_touches=2)
    assert set(free._touch_counts(200).tolist()) == {0, 1, 2}  # some samples train with no touch at all
    with pytest.raises(ValueError, match="tactile_only model needs at least one touch"):
        ReconstructionModule(_net("tactile_only"), _optimizer, min_touches=0)


def test_recon_touch_free_share() -> None:
    """touch_free_share p: about p of the samples have no touch, the others 1..max_touches, uniform."""
    torch.manual_seed(0)
    model = ReconstructionModule(_net(), _optimizer, min_touches=0, max_touches=4, touch_free_share=0.4)
    counts = model._touch_counts(20000)
    free = (counts == 0).float().mean().item()
    assert abs(free - 0.4) < 0.02  # not the 1 / 5 that uniform counts in [0, 4] would give
    touched = counts[counts > 0]
    assert set(touched.tolist()) == {1, 2, 3, 4}
    assert torch.bincount(touched)[1:].float().div(len(touched)).sub(0.25).abs().max() < 0.02
    none = ReconstructionModule(_net(), _optimizer, min_touches=2, max_touches=3, touch_free_share=0.0)
    assert set(none._touch_counts(200).tolist()) == {2, 3}  # min_touches still bounds the touched samples
    with pytest.raises(ValueError, match="touch_free_share must be in"):
        ReconstructionModule(_net(), _optimizer, touch_free_share=1.0)
    with pytest.raises(ValueError, match="tactile_only model needs at least one touch"):
        ReconstructionModule(_net("tactile_only"), _optimizer, touch_free_share=0.2)


@pytest.mark.filterwarnings("ignore:You are trying to `self.log")
def test_recon_training_step_with_touch_free_samples() -> None:
    """min_touches=0: a batch mixing touch-free and touched samples trains; a batch drawn all touch-free runs the
    model's own no-touch path."""
    torch.manual_seed(0)
    model = ReconstructionModule(_net(), _optimizer, min_touches=0, max_touches=10)
    dm = SyntheticReconDataModule(batch_size=2, n=2)
    dm.setup("fit")
    sample = next(iter(dm.train_dataloader()))
    for counts in (torch.tensor([0, 3]), torch.tensor([0, 0])):
        model._touch_counts = lambda n, c=counts: c  # type: ignore[method-assign]
        loss = model.training_step(sample, 0)
        assert torch.isfinite(loss)
        loss.backward()


@pytest.mark.slow
def test_classification_fit_test_and_learns(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = TactileClassifier(num_classes=3, num_touches=2)
    model = ClassificationModule(
        net,
        _optimizer,
        num_touches=2,
        touch_sampling="random",
        eval_touches=[1, 2, 4],
        name="classify",
        seed=0,
        controls=["other"],
    )
    assert model.eval_touches == [1, 2]  # 4 > the trained N is dropped
    dm = SyntheticClassificationDataModule(batch_size=6, n=6, num_touches=2, tactile_size=8)
    trainer = _trainer(tmp_path, max_epochs=25, limit_val_batches=1)
    trainer.fit(model, dm)
    trainer.test(model, dm)
    res = model.test_results
    assert res["task"] == "classification" and set(res["accuracy"]) == {"1", "2"}
    assert res["accuracy"]["2"] > 0.5  # 3 separable classes: far above chance (1/3)
    for k in ("1", "2"):  # the confusion matrix and per-class accuracy agree with the accuracy
        matrix = torch.tensor(res["confusion"][k])
        assert matrix.shape == (3, 3) and int(matrix.sum()) == len(dm.test_dataloader().dataset)
        assert int(matrix.diagonal().sum()) / int(matrix.sum()) == pytest.approx(res["accuracy"][k])
        rows = matrix.sum(1)
        expected = {res["classes"][c]: int(matrix[c, c]) / int(rows[c]) for c in range(3) if rows[c] > 0}
        assert res["per_class"][k] == pytest.approx(expected)
    assert len(res["classes"]) == 3
    # another object's touches (another label, the class is in the images) score at most what the model gets wrong
    assert set(res["accuracy_other"]) == {"1", "2"}
    assert res["accuracy_other"]["2"] <= 1.0 - res["accuracy"]["2"] + 1e-9 and res["accuracy_other"]["2"] < 0.34
    with pytest.raises(ValueError, match="unknown classification controls"):
        ClassificationModule(net, _optimizer, num_touches=2, controls=["blank"])
    with pytest.raises(ValueError, match="num_touches must be in"):
        ClassificationModule(TactileClassifier(num_classes=3, num_touches=2), _optimizer, num_touches=3)


def test_other_object_index_pairs_samples_with_another_label() -> None:
    idx, valid = other_object_index(torch.tensor([0, 0, 1, 1, 1, 2]))
    assert idx.tolist() == [2, 2, 5, 5, 5, 0] and valid.all()
    idx, valid = other_object_index(torch.tensor([4, 4, 4]))
    assert idx.tolist() == [0, 1, 2] and not valid.any()  # nobody else: never counted
    idx, valid = other_object_index(torch.tensor([3]))
    assert idx.tolist() == [0] and not valid.any()


class _PositionNet(torch.nn.Module):
    """Reads two per-touch inputs: the class is the x coordinate of the first touch's position."""

    touch_inputs = ("tactile", "positions")
    num_touches = 4

    def forward(self, tactile: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        assert tactile.shape[:2] == positions.shape[:2]
        return torch.nn.functional.one_hot(positions[:, 0, 0].long(), 3).float()


def test_every_input_the_net_reads_gets_the_same_touches() -> None:
    model = ClassificationModule(_PositionNet(), _optimizer, num_touches=2)
    mask = torch.tensor([[False, True, True, True], [True, False, True, False]])
    positions = torch.arange(4.0)[None, :, None].expand(2, 4, 3).clone()  # touch t at x = t
    tactile = torch.arange(4.0)[None, :, None, None, None].expand(2, 4, 3, 2, 2).clone()
    batch = {"tactile": tactile, "positions": positions, "touch_mask": mask, "label": torch.tensor([1, 0])}
    t, p = model._inputs(batch, 2)
    assert p[:, :, 0].tolist() == [[1.0, 2.0], [0.0, 2.0]]  # the first valid touches
    assert torch.equal(t[:, :, 0, 0, 0], p[:, :, 0])  # the same touches in both inputs
    assert model(t, p).argmax(1).tolist() == [1, 0]
    with pytest.raises(KeyError, match="data.patches=true"):
        ClassificationModule(_PatchNet(), _optimizer, num_touches=2)._inputs(batch, 2)


class _PatchNet(_PositionNet):
    touch_inputs = ("tactile", "patch_points")


def test_touch_controls_replace_the_touch_content(tmp_path: Path) -> None:
    batch = {
        "tactile": torch.arange(3.0)[:, None, None, None, None].expand(3, 2, 3, 4, 4).clone(),
        "directions": torch.arange(3.0)[:, None, None].expand(3, 2, 3).clone(),
        "positions": torch.randn(3, 2, 3),
    }
    other = ReconstructionModule.control_batch(batch, "other")
    assert other["tactile"][:, 0, 0, 0, 0].tolist() == [1.0, 2.0, 0.0]  # the next sample's touches
    assert other["directions"][:, 0, 0].tolist() == [1.0, 2.0, 0.0]
    assert other["positions"] is batch["positions"] and batch["tactile"][0].sum() == 0  # input left alone
    blank = ReconstructionModule.control_batch(batch, "blank")
    assert blank["tactile"].abs().sum() == 0 and blank["directions"] is batch["directions"]
    assert ReconstructionModule.control_batch({k: v[:1] for k, v in batch.items()}, "other") is None
    with pytest.raises(ValueError, match="control must be one of"):
        ReconstructionModule.control_batch(batch, "shuffle")

    model = ReconstructionModule(
        _net("tactile_only"), _optimizer, eval_touches=(2, 5), metric_points=200, name="tactile_only",
        export=False, render_every_n_epochs=0, touch_controls=True,
    )  # fmt: skip
    dm = SyntheticReconDataModule(batch_size=2, n=4)
    trainer = _trainer(tmp_path, max_epochs=1, limit_train_batches=1, limit_val_batches=1, limit_test_batches=2)
    trainer.fit(model, dm)
    trainer.test(model, dm)
    modes = model.test_results["modes"]
    assert set(modes) == {
        "tactile@2",
        "tactile@5",
        "tactile@2:other",
        "tactile@2:blank",
        "tactile@5:other",
        "tactile@5:blank",
    }
    assert modes["tactile@5:other"]["count"] == modes["tactile@5"]["count"] == 4
    assert modes["tactile@5:blank"]["chamfer"] != modes["tactile@5"]["chamfer"]


def test_refine_modes_for_visual_only_and_fusion(tmp_path: Path) -> None:
    dm = SyntheticReconDataModule(batch_size=2, n=4)
    for mode, expected in (
        ("visual_only", {"visual", "visual+refine@2", "visual+refine@5"}),
        ("fusion", {"visual", "tv@2", "tv@5", "tv@2+refine", "tv@5+refine"}),
    ):
        model = ReconstructionModule(
            _net(mode), _optimizer, eval_touches=(2, 5), metric_points=200, name=mode,
            export=False, render_every_n_epochs=0, refine=True, refine_steps=20,
        )  # fmt: skip
        trainer = _trainer(tmp_path / mode, max_epochs=1, limit_train_batches=1, limit_val_batches=1)
        trainer.fit(model, dm)
        trainer.test(model, dm)
        modes = model.test_results["modes"]
        assert set(modes) == expected
        base = "visual" if mode == "visual_only" else "tv@5"
        refined = "visual+refine@5" if mode == "visual_only" else "tv@5+refine"
        # the untrained mesh is far from the sphere's surface: pulling it onto surface points lowers the chamfer
        assert modes[refined]["chamfer"] < modes[base]["chamfer"]
        assert modes[refined]["touches"] > 0
