"""The cheaper training step computes the same function: graph-conv input parts, the prebuilt transpose, the
chamfer search, mixed precision kept out of the geometry, the precision resolver and the channels_last switch."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from tvrecon.losses.chamfer import chamfer_terms, nearest_neighbors
from tvrecon.models import precision
from tvrecon.models.components.gcn import (
    GraphConv,
    MeshDeformer,
    neighbour_matrix,
    neighbour_operator,
)
from tvrecon.models.components.perceptual import PerceptualPooling, bilinear_weights
from tvrecon.models.components.projection import camera_to_pixel
from tvrecon.models.precision import (
    best_precision,
    cpu_bf16_is_faster,
    cpu_has_native_bf16,
    register_precision_resolver,
)


def _view(B: int = 2, H: int = 32) -> tuple[list[torch.Tensor], torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    sizes = ((3, 1), (4, 2), (8, 4), (16, 8))  # a 32x32 map sampled by grid_sample, the others by their weights
    feats = [torch.randn(B, c, H // s, H // s, generator=g, dtype=torch.float64) for c, s in sizes]
    K = torch.tensor([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]], dtype=torch.float64).repeat(B, 1, 1)
    return feats, K


def test_graph_conv_reads_its_input_as_parts() -> None:
    """concat([hidden, x, pooled, extra]) through one conv equals the parts with the sample left unevaluated (both
    ways of projecting a map are taken), values and gradients."""
    torch.manual_seed(0)
    feats, K = _view()
    verts = torch.randn(2, 40, 3, dtype=torch.float64) * 0.2 + torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)
    hidden = torch.randn(2, 40, 5, dtype=torch.float64, requires_grad=True)
    extra = torch.randn(2, 40, 2, dtype=torch.float64)
    edges = torch.stack([torch.arange(39), torch.arange(1, 40)], dim=1)
    conv = GraphConv(5 + 3 + 31 + 2, 6).double()
    pool = PerceptualPooling()
    maps = [f.requires_grad_(True) for f in feats]
    dense = conv(torch.cat([hidden, verts, pool(verts, K, maps, (32, 32)), extra], dim=-1), edges)
    grads_dense = torch.autograd.grad(dense.square().sum(), [hidden, *maps])
    parts = conv([hidden, verts, pool.sample(verts, K, maps, (32, 32)), extra], edges)
    grads_parts = torch.autograd.grad(parts.square().sum(), [hidden, *maps])
    assert torch.allclose(parts, dense, atol=1e-10)
    assert all(torch.allclose(a, b, atol=1e-10) for a, b in zip(grads_parts, grads_dense))
    with pytest.raises(ValueError, match="x must have 41 channels in all its parts, got 40"):
        conv([hidden, verts, pool.sample(verts, K, maps, (32, 32)), extra[..., :1]], edges)


def test_bilinear_weights_are_grid_samples() -> None:
    """Rows of four weights reproduce grid_sample (bilinear, border, align_corners=False), gradients in the grid too,
    also for positions outside the map and on its border."""
    g = torch.Generator().manual_seed(2)
    f = torch.randn(2, 5, 6, 7, generator=g, dtype=torch.float64)
    grid = (torch.rand(2, 30, 1, 2, generator=g, dtype=torch.float64) * 2.6 - 1.3).requires_grad_(True)
    ref = torch.nn.functional.grid_sample(f, grid, mode="bilinear", padding_mode="border", align_corners=False)
    ref = ref[..., 0].transpose(1, 2)  # (B, V, C)
    S = bilinear_weights(grid, 6, 7)
    got = S @ f.flatten(2).transpose(1, 2)
    assert S.shape == (2, 30, 42) and torch.allclose(S.sum(-1), torch.ones(2, 30, dtype=torch.float64))
    assert torch.allclose(got, ref, atol=1e-12)
    probe = torch.randn(2, 30, 5, generator=g, dtype=torch.float64)
    (g_ref,) = torch.autograd.grad((ref * probe).sum(), grid)
    (g_got,) = torch.autograd.grad((got * probe).sum(), grid)
    assert torch.allclose(g_got, g_ref, atol=1e-10)


def test_prebuilt_transpose_gives_the_same_gradients() -> None:
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3], [3, 4]])
    conv = GraphConv(4, 3, "mean").double()
    x = torch.randn(2, 5, 4, dtype=torch.float64, requires_grad=True)
    op = neighbour_operator(edges, 5, "mean", batch_size=2)
    assert torch.equal(op.transpose.to_dense(), neighbour_matrix(edges, 5, "mean", 2).to_dense().T)
    assert torch.allclose(conv(x, edges, op), conv(x, edges), atol=1e-12)
    assert torch.autograd.gradcheck(lambda t: conv(t, edges, op), (x,))


def test_chamfer_search_matches_brute_force_and_ignores_autocast() -> None:
    g = torch.Generator().manual_seed(1)
    x = torch.randn(2, 300, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 2.0])
    y = torch.randn(2, 200, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 2.0])
    brute = torch.cdist(x.double(), y.double()).argmin(2)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        dist, idx = nearest_neighbors(x, y)
        terms = chamfer_terms(x, y)
    assert torch.equal(idx, brute) and dist.dtype == torch.float32
    assert torch.equal(terms.idx_yx, torch.cdist(y.double(), x.double()).argmin(2))


def test_projection_stays_float32_under_autocast() -> None:
    points = torch.tensor([[[0.1234, -0.0567, 2.0]]])
    K = torch.tensor([[[277.0, 0.0, 63.5], [0.0, 277.0, 63.5], [0.0, 0.0, 1.0]]])
    plain = camera_to_pixel(points, K)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        mixed = camera_to_pixel(points, K)
    assert mixed.dtype == torch.float32 and torch.equal(mixed, plain)


def test_deformer_under_autocast_stays_close_to_float32() -> None:
    torch.manual_seed(0)
    deformer = MeshDeformer(feature_channels=[8, 16], hidden=16, num_blocks=1)
    feats = [torch.randn(2, 8, 16, 16), torch.randn(2, 16, 8, 8)]
    K = torch.tensor([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]]).repeat(2, 1, 1)
    ref = deformer(feats, K, (32, 32))["verts"][-1]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        mixed = deformer(feats, K, (32, 32))["verts"][-1]
    assert mixed.dtype == torch.float32
    assert (mixed - ref).abs().max() < 1e-2  # bfloat16 products, float32 geometry


def test_best_precision(tmp_path: Path) -> None:
    with_bf16 = tmp_path / "bf16"
    with_bf16.write_text("processor\t: 0\nflags\t\t: fpu avx512f avx512_bf16 sse\n")
    without = tmp_path / "plain"
    without.write_text("processor\t: 0\nflags\t\t: fpu avx2 avx512f\n")
    assert cpu_has_native_bf16(with_bf16) and not cpu_has_native_bf16(without)
    assert not cpu_has_native_bf16(tmp_path / "missing")
    expected = "bf16-mixed" if cpu_has_native_bf16() and cpu_bf16_is_faster() else "32-true"
    assert best_precision("cpu") == expected
    assert best_precision("mps") == "32-true"
    if not torch.cuda.is_available():
        assert best_precision("gpu") == "32-true" and best_precision("auto") == expected
    with pytest.raises(ValueError, match="accelerator must be one of"):
        best_precision("abacus")
    register_precision_resolver()
    cfg = OmegaConf.create({"accelerator": "cpu", "precision": "${best_precision:${accelerator}}"})
    assert cfg.precision == expected


def test_bf16_is_chosen_only_where_the_probe_finds_it_faster(monkeypatch: pytest.MonkeyPatch) -> None:
    # the probe's decision: bf16 within PROBE_MARGIN of float32's time, timed on a small real product
    assert isinstance(cpu_bf16_is_faster((64, 16, 16), 1), bool)
    for bf16_seconds, faster in ((0.5, True), (0.9, True), (0.95, False), (1.4, False)):
        monkeypatch.setattr(
            precision, "_product_seconds", lambda bf16, shape, repeats, s=bf16_seconds: s if bf16 else 1.0
        )
        cpu_bf16_is_faster.cache_clear()
        assert cpu_bf16_is_faster() is faster
    cpu_bf16_is_faster.cache_clear()
    # native bf16 by the flags but slower by the probe (an Intel Xeon without AMX): float32
    monkeypatch.setattr(precision, "cpu_has_native_bf16", lambda: True)
    monkeypatch.setattr(precision, "cpu_bf16_is_faster", lambda: False)
    assert best_precision("cpu") == "32-true"
    monkeypatch.setattr(precision, "cpu_bf16_is_faster", lambda: True)
    assert best_precision("cpu") == "bf16-mixed"
    monkeypatch.setattr(precision, "cpu_has_native_bf16", lambda: False)
    assert best_precision("cpu") == "32-true"  # no native bf16: no probe, float32


def test_channels_last_switch_keeps_the_function() -> None:
    from tvrecon.models.components.backbone import ResNet18Backbone
    from tvrecon.models.lit_recon import ReconstructionModule

    torch.manual_seed(0)
    net = ResNet18Backbone().eval()  # running statistics: the output does not hinge on a batch of two
    x = torch.rand(2, 3, 64, 64)
    ref = net(x)[-1]
    module = ReconstructionModule(net, torch.optim.AdamW, channels_last=True)
    assert net.stem[0].weight.is_contiguous(memory_format=torch.channels_last)
    assert torch.allclose(module.net(x)[-1], ref, atol=1e-4)


def test_bfloat16_neighbour_product_on_the_cpu() -> None:
    """bfloat16 features take the operator's bfloat16 COO matrices: close to float32, gradients included."""
    torch.manual_seed(0)
    edges = torch.tensor([[0, 1], [1, 2], [0, 2], [2, 3], [3, 4], [0, 4]])
    op = neighbour_operator(edges, 5, "mean", batch_size=3)
    conv = GraphConv(8, 6)
    x = torch.randn(3, 5, 8, requires_grad=True)
    ref = conv(x, edges, op)
    (g_ref,) = torch.autograd.grad(ref.square().sum(), x)
    xb = x.detach().bfloat16().requires_grad_(True)
    out = conv.bfloat16()(xb, edges, op)
    (g_out,) = torch.autograd.grad(out.float().square().sum(), xb)
    assert out.dtype == torch.bfloat16 and set(op.bfloat16) == {"coo"}
    assert torch.allclose(out.float(), ref, atol=0.05, rtol=0.02)
    assert torch.allclose(g_out.float(), g_ref, atol=0.1, rtol=0.05)
