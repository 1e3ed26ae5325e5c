"""The Chart-based reconstructor (Smith et al. 2020): output shapes in every mode, touch charts held fixed, gradient
flow to every parameter, a one-sample overfit, and the LightningModule's fit and test protocol with touch controls."""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import pytest
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset

from tvrecon.losses.charts import ChartLoss, sampled_chamfer
from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.chart_based import ChartBasedReconstructor
from tvrecon.models.components.chart_deformer import ChartDeformer
from tvrecon.models.components.charts import ChartTemplate
from tvrecon.models.components.touch_charts import TouchChartPredictor, fit_touch_charts
from tvrecon.models.lit_recon import ReconstructionModule
from tvrecon.utils.geometry import world_to_camera

H, PAD = 64, 6  # view size; the pads' contact layer is PAD x PAD
VV, VT = 20 * 10, 25  # small layout (icosahedron, 3 segments per chart side); touch chart 5 x 5


def _sample(i: int, T: int = 4, radius: float = 0.3, shift: float = 0.0) -> dict[str, torch.Tensor]:
    """A sphere of ``radius`` at the origin seen from z = -2 (the camera moved by ``shift`` along -x), with T touches
    whose contact layers lie on it."""
    g = torch.Generator().manual_seed(i)
    f = 0.5 * H / math.tan(math.radians(35.0) / 2)
    normals = F.normalize(torch.randn(512, 3, generator=g), dim=-1)
    d = F.normalize(torch.randn(T, 3, generator=g), dim=-1)
    s = torch.linspace(-0.06, 0.06, PAD)
    yy, xx = torch.meshgrid(s, s, indexing="ij")
    ref = torch.where(d[:, :1].abs() < 0.9, torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 1, 0]))
    ex = F.normalize(torch.linalg.cross(d, ref), dim=-1)
    ey = torch.linalg.cross(d, ex)
    layer = d[:, None] + xx.reshape(1, -1, 1) * ex[:, None] + yy.reshape(1, -1, 1) * ey[:, None]  # (T, Q, 3)
    layer = F.normalize(layer, dim=-1) * radius
    valid = torch.arange(T) < 1 + i % T
    return {
        "image": torch.rand(3, H, H, generator=g),
        "K": torch.tensor([[f, 0.0, (H - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]]),
        "RT": torch.cat([torch.eye(3), torch.tensor([[shift], [0.0], [2.0]])], dim=1),
        "tactile": torch.rand(T, 3, 8, 8, generator=g) * valid[:, None, None, None],
        "positions": d * radius * valid[:, None],
        "directions": -d * valid[:, None],
        "touch_mask": valid,
        "points": normals * radius,
        "normals": normals,
        "label": torch.tensor(i % 2),
        "patch_points": layer * valid[:, None, None],
        "patch_normals": F.normalize(layer, dim=-1) * valid[:, None, None],
        "patch_mask": valid[:, None].expand(T, PAD * PAD).clone(),
    }


def _batch(B: int = 2, T: int = 4, **kw: float) -> dict[str, torch.Tensor]:
    samples = [_sample(i + 1, T, **kw) for i in range(B)]
    return {k: torch.stack([s[k] for s in samples]) for k in samples[0]}


def _net(mode: str = "chart_based", source: str = "patch", seed: int = 0, hidden: int = 16) -> ChartBasedReconstructor:
    torch.manual_seed(seed)
    image = mode != "chart_based_tactile"
    backbone = ResNet18Backbone() if image else None
    deformer = ChartDeformer(ResNet18Backbone.channels, hidden=hidden, num_layers=3, iterations=2, use_image=image)
    predictor = TouchChartPredictor((PAD, PAD), 0.5, 40, 6.25, channels=(4, 8)) if source == "predicted" else None
    template = ChartTemplate(base_subdivisions=0, chart_subdivisions=3)
    return ChartBasedReconstructor(backbone, deformer, template, predictor, mode=mode, touch_chart=source)


def _run(net: ChartBasedReconstructor, b: dict[str, torch.Tensor], touches: bool = True) -> dict:
    if not touches:
        return net(b["image"], b["K"], b["RT"])
    keys = ("tactile", "positions", "directions", "touch_mask", "patch_points", "patch_normals", "patch_mask")
    return net(b["image"], b["K"], b["RT"], *(b[k] for k in keys))


def _camera_points(b: dict[str, torch.Tensor]) -> torch.Tensor:
    return world_to_camera(b["points"], b["RT"])


@pytest.mark.parametrize("source", ["patch", "predicted"])
def test_output_shapes_and_touch_slots(source: str) -> None:
    b = _batch(B=2, T=4)  # sample 0 uses 2 touches, sample 1 uses 3
    out = _run(_net(source=source), b)
    V = VV + 4 * VT
    assert len(out["verts"]) == len(out["verts_before"]) == len(out["faces"]) == 2  # one entry per pass
    for v, vb, fc, e in zip(out["verts"], out["verts_before"], out["faces"], out["edges"]):
        assert v.shape == vb.shape == (2, V, 3) and fc.shape == (20 * 9 + 4 * 32, 3) and e.shape[1] == 2
        assert int(fc.max()) == V - 1 and torch.isfinite(v).all()
    assert out["init_verts"][0].shape == (V, 3) and len(out["features"]) == 4
    assert out["touch_charts"].shape == (2, 4, VT, 3)
    assert out["touch_used"].tolist() == [[True, True, False, False], [True, True, True, False]]
    assert ("touch_chart_loss" in out) == (source == "predicted")
    # no touch: the vision charts alone
    alone = _run(_net(source=source), b, touches=False)
    assert alone["verts"][-1].shape == (2, VV, 3) and alone["touch_charts"] is None


def test_modes_visual_and_tactile() -> None:
    b = _batch()
    visual = _run(_net("chart_based_visual"), b)  # never reads touches
    assert visual["verts"][-1].shape == (2, VV, 3) and visual["touch_used"] is None
    net = _net("chart_based_tactile")
    assert net.visual is None
    out = _run(net, b)
    b2 = dict(b, image=torch.rand_like(b["image"]))
    assert torch.equal(out["verts"][-1], _run(net, b2)["verts"][-1])  # the view is not read
    with pytest.raises(ValueError, match="needs touches"):
        _run(net, b, touches=False)


def test_touch_charts_are_held_fixed() -> None:
    b = _batch()
    net = _net(source="predicted")
    out = _run(net, b)
    used = out["touch_used"]
    # the charts are those of the contact points, placed in the camera frame...
    idx = torch.nonzero(b["touch_mask"].reshape(-1), as_tuple=True)[0]
    origins, dirs = b["positions"].reshape(-1, 3)[idx], b["directions"].reshape(-1, 3)[idx]
    pts, mask = net.touch_predictor(b["tactile"].flatten(0, 1)[idx], origins, dirs)
    charts, _ = fit_touch_charts(pts, mask, origins, dirs)
    first = out["touch_charts"].reshape(-1, VT, 3)[idx]
    cam = world_to_camera(charts.reshape(1, -1, 3), b["RT"][:1]).reshape_as(first)
    assert torch.allclose(first, cam, atol=1e-5)
    for v in out["verts"]:  # ...and every pass keeps them where they are; unused ones collapse onto vertex 0
        slots = v[:, VV:].reshape(2, 4, VT, 3)
        assert torch.equal(slots[used], out["touch_charts"][used])
        assert torch.equal(slots[~used], v[:, :1, None].expand(-1, 4, VT, 3)[~used])
    # the global loss moves no touch chart: no gradient reaches the touch network from it
    ChartLoss()(out, _camera_points(b), b["normals"])["chamfer"].backward()
    assert all(p.grad is None for p in net.touch_predictor.parameters())
    assert not out["touch_charts"].requires_grad


@pytest.mark.parametrize("source", ["patch", "predicted"])
def test_gradient_reaches_every_parameter(source: str) -> None:
    b = _batch()
    net = _net(source=source)
    out = _run(net, b)
    ChartLoss()(out, _camera_points(b), b["normals"])["loss"].backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not bool(p.grad.abs().sum() > 0)]
    assert not missing, missing


def test_overfits_one_sample() -> None:
    b = _batch(B=1, radius=0.45, shift=0.15)  # larger than the initial layout and off its centre
    net = _net(hidden=32)
    net.train()
    target = _camera_points(b)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    loss_fn = ChartLoss(num_samples=512)

    def measured() -> float:
        with torch.no_grad():
            out = _run(net, b)
            g = torch.Generator().manual_seed(0)
            return float(sampled_chamfer(out["verts"][-1], out["faces"][-1], target, 2000, g).mean())

    start = measured()
    for _ in range(40):
        loss = loss_fn(_run(net, b), target, b["normals"])["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert measured() < 0.3 * start


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="mode must be one of"):
        ChartBasedReconstructor(mode="fusion")
    with pytest.raises(ValueError, match="touch_chart must be one of"):
        ChartBasedReconstructor(touch_chart="exact")
    with pytest.raises(ValueError, match="set model.net.deformer"):
        ChartBasedReconstructor(deformer=torch.nn.Linear(1, 1))
    with pytest.raises(ValueError, match="use_image=false"):
        ChartBasedReconstructor(chart_deformer=ChartDeformer(use_image=True), mode="chart_based_tactile")
    net = _net()
    b = _batch()
    with pytest.raises(ValueError, match="reads the contact patches"):
        net(b["image"], b["K"], b["RT"], b["tactile"], b["positions"], b["directions"], b["touch_mask"])


class _Samples(Dataset):
    def __len__(self) -> int:
        return 4

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return _sample(i)


def test_lightning_fit_and_test_protocol(tmp_path: Path) -> None:
    model = ReconstructionModule(
        _net(), lambda params: torch.optim.Adam(params, lr=3e-4), criterion=ChartLoss(num_samples=256),
        min_touches=0, max_touches=4, eval_touches=(2, 4), metric_points=200, name="chart_based", export=False,
        render_every_n_epochs=0, class_names=["bottle", "bowl"], touch_controls=True, lr_scales=None,
    )  # fmt: skip
    assert model.modality == "tactile_visual"
    loader = DataLoader(_Samples(), batch_size=2)
    trainer = L.Trainer(
        accelerator="cpu", devices=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, max_epochs=1, limit_train_batches=1, limit_val_batches=1, limit_test_batches=2,
        default_root_dir=str(tmp_path),
    )  # fmt: skip
    trainer.fit(model, loader, loader)
    for key in ("train/loss", "train/chamfer", "val/chamfer"):
        assert torch.isfinite(trainer.callback_metrics[key])
    trainer.test(model, loader)
    modes = model.test_results["modes"]
    assert set(modes) == {"visual", "tv@2", "tv@4", "tv@2:other", "tv@2:blank", "tv@4:other", "tv@4:blank"}
    assert all(m["count"] == 4 and m["chamfer"] > 0 for m in modes.values())
    for mode, modality in (("chart_based_visual", "visual"), ("chart_based_tactile", "tactile")):
        lit = ReconstructionModule(_net(mode), torch.optim.Adam, criterion=ChartLoss(), min_touches=1)
        assert lit.modality == modality
