"""Reconstructor: output contract, modes, gradient flow and overfitting a tiny batch."""

import pytest
import torch

from tvrecon.losses.mesh import mesh_loss_terms
from tvrecon.models.components.fusion import TactileVisualFusion
from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.models.components.reconstructor import TactileVisualReconstructor

H = 32


def small_net(mode: str = "fusion", **fusion_kw) -> TactileVisualReconstructor:
    fusion = TactileVisualFusion(**fusion_kw) if mode != "visual_only" else None
    deformer = MeshDeformer(hidden=16, num_blocks=1, rings=5, segments=6)
    return TactileVisualReconstructor(fusion=fusion, deformer=deformer, mode=mode)


def batch(B: int = 2, T: int = 3) -> dict[str, torch.Tensor]:
    K = torch.tensor([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]]).repeat(B, 1, 1)
    RT = torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], dim=1).repeat(B, 1, 1)
    g = torch.Generator().manual_seed(0)
    return {
        "image": torch.rand(B, 3, H, H, generator=g),
        "K": K,
        "RT": RT,
        "tactile": torch.rand(B, T, 3, 16, 16, generator=g),
        "positions": (torch.rand(B, T, 3, generator=g) - 0.5) * 0.4,
        "directions": torch.nn.functional.normalize(torch.randn(B, T, 3, generator=g), dim=-1),
        "touch_mask": torch.ones(B, T, dtype=torch.bool),
    }


def run(net: TactileVisualReconstructor, b: dict, **over) -> dict:
    args = {**b, **over}
    return net(
        args["image"], args["K"], args["RT"], args["tactile"], args["positions"], args["directions"], args["touch_mask"]
    )


def test_output_contract() -> None:
    net = small_net().eval()
    out = run(net, batch())
    V = [32, 122, 482]  # 5 rings x 6 segments + 2 poles, then V + E at each unpooling
    assert [tuple(v.shape) for v in out["verts"]] == [(2, n, 3) for n in V]
    assert [tuple(v.shape) for v in out["verts_before"]] == [(2, n, 3) for n in V]
    assert [tuple(v.shape) for v in out["init_verts"]] == [(n, 3) for n in V]
    assert [f.shape[0] for f in out["faces"]] == [2 * n - 4 for n in V]
    assert [e.shape[0] for e in out["edges"]] == [3 * n - 6 for n in V]
    assert all(f.dtype == torch.int64 for f in out["faces"] + out["edges"])
    assert [tuple(f.shape[1:]) for f in out["features"]] == [(64, 8, 8), (128, 4, 4), (256, 2, 2), (512, 1, 1)]


def test_default_deformer_sizes() -> None:
    net = TactileVisualReconstructor(deformer=MeshDeformer(hidden=8, num_blocks=0)).eval()
    b = batch(B=1, T=1)
    with torch.no_grad():
        out = run(net, b)
    assert [v.shape[1] for v in out["verts"]] == [156, 618, 2466]


def test_modes() -> None:
    b = batch()
    visual = small_net("visual_only").eval()
    assert visual.tactile is None and visual.fusion is None
    out_none = visual(b["image"], b["K"], b["RT"])
    out_t = run(visual, b)  # touches are ignored
    assert torch.equal(out_none["verts"][-1], out_t["verts"][-1])

    tactile = small_net("tactile_only").eval()
    a = run(tactile, b)
    c = run(tactile, b, image=torch.rand(2, 3, H, H))  # the view is blanked
    assert torch.equal(a["verts"][-1], c["verts"][-1])
    with pytest.raises(ValueError, match="tactile_only"):
        tactile(b["image"], b["K"], b["RT"])

    fusion = small_net(zero_init=False).eval()  # non-zero Agg scales: touches change the output
    no_touch = fusion(b["image"], b["K"], b["RT"])
    masked = run(fusion, b, touch_mask=torch.zeros(2, 3, dtype=torch.bool))
    touched = run(fusion, b)
    assert torch.equal(no_touch["verts"][-1], masked["verts"][-1])
    assert not torch.allclose(no_touch["verts"][-1], touched["verts"][-1])
    # a touch of sample 0 does not change sample 1
    mask = torch.tensor([[True, False, False], [False, False, False]])
    one = run(fusion, b, touch_mask=mask)
    assert torch.allclose(one["verts"][-1][1], no_touch["verts"][-1][1], atol=1e-5)  # kernels may round differently
    assert not torch.allclose(one["verts"][-1][0], no_touch["verts"][-1][0])

    with pytest.raises(ValueError, match="mode"):
        TactileVisualReconstructor(mode="both")
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        fusion(torch.rand(2, 1, H, H), b["K"], b["RT"])
    with pytest.raises(ValueError, match=r"K must have shape \(B, 3, 3\), got \(2, 2, 3\)"):
        fusion(b["image"], b["K"][:, :2], b["RT"])
    with pytest.raises(ValueError, match=r"K must be \(B, 3, 3\) and RT \(B, 3, 4\) with B=2"):
        fusion(b["image"], b["K"][:1], b["RT"])
    with pytest.raises(ValueError, match=r"positions must have shape \(B, T, 3\), got \(2, 3\)"):
        run(fusion, b, positions=torch.rand(2, 3))


def _grad_norm(module: torch.nn.Module) -> float:
    return sum(p.grad.abs().sum().item() for p in module.parameters() if p.grad is not None)


def _backward(net: TactileVisualReconstructor, b: dict) -> None:
    net.zero_grad()
    out = run(net, b)
    gt = torch.rand(2, 50, 3, generator=torch.Generator().manual_seed(3)) + torch.tensor([0.0, 0.0, 1.5])
    terms = mesh_loss_terms(out, gt, torch.nn.functional.normalize(torch.ones(2, 50, 3), dim=-1))
    terms["loss"].backward()


def test_gradients_reach_both_branches_and_direction_ffn() -> None:
    torch.manual_seed(0)
    net = small_net().train()
    b = batch()
    _backward(net, b)
    # zero-initialised Agg scales: at the start only those scales (and the visual path) get a gradient
    assert _grad_norm(net.visual.stem) > 0 and _grad_norm(net.deformer) > 0
    assert all(agg.net[-1].weight.grad.abs().sum() > 0 for agg in net.fusion.aggs.values())
    assert _grad_norm(net.tactile) == 0 and _grad_norm(net.fusion.direction_ffn) == 0
    # one optimizer step opens every path: the tactile branch, the direction FFN and every Agg block
    torch.optim.SGD(net.parameters(), lr=0.1).step()
    _backward(net, b)
    assert _grad_norm(net.tactile.stem) > 0
    assert _grad_norm(net.tactile.stages[3]) > 0
    assert _grad_norm(net.fusion.direction_ffn) > 0
    assert all(_grad_norm(agg.net[0]) > 0 for agg in net.fusion.aggs.values())


def test_gradients_flow_everywhere_without_zero_init() -> None:
    net = small_net(zero_init=False).train()
    _backward(net, batch())
    assert _grad_norm(net.tactile.stem) > 0 and _grad_norm(net.fusion.direction_ffn) > 0
    assert all(_grad_norm(agg) > 0 for agg in net.fusion.aggs.values())


def test_untrained_fusion_model_equals_its_visual_path() -> None:
    """Zero-init Agg blocks: the touches change nothing until training gives them weight."""
    net = small_net().eval()
    b = batch()
    with torch.no_grad():
        with_touches = run(net, b)["verts"][-1]
        without = run(net, b, tactile=None)["verts"][-1]
        assert torch.allclose(with_touches, without, atol=1e-6)  # adds exact zeros; kernels may round differently
        net_plain = small_net(zero_init=False).eval()
        net_plain.load_state_dict(net.state_dict(), strict=False)
        for agg in net_plain.fusion.aggs.values():
            torch.nn.init.ones_(agg.net[-1].weight)
        assert not torch.allclose(run(net_plain, b)["verts"][-1], without)


def test_directions_enter_in_the_camera_frame() -> None:
    """Rotating the world (view, touches and directions together) leaves the camera-frame prediction unchanged."""
    torch.manual_seed(0)
    net = small_net().eval()
    for agg in net.fusion.aggs.values():
        torch.nn.init.ones_(agg.net[-1].weight)
    b = batch()
    angle = torch.tensor(0.7)
    c, s = torch.cos(angle), torch.sin(angle)
    Q = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # world rotation about z
    rotated = dict(b)
    rotated["positions"] = b["positions"] @ Q.T
    rotated["directions"] = b["directions"] @ Q.T
    R, t = b["RT"][:, :, :3], b["RT"][:, :, 3:]
    rotated["RT"] = torch.cat([R @ Q.T, t], dim=2)  # same camera relative to the rotated world
    with torch.no_grad():
        a = run(net, b)["verts"][-1]
        r = run(net, rotated)["verts"][-1]
    assert torch.allclose(a, r, atol=1e-5)


@pytest.mark.slow
def test_overfits_two_samples() -> None:
    """Random init, tiny images and widths: the chamfer of the final mesh falls by >= 90% on two samples."""
    torch.manual_seed(0)
    net = small_net()
    net.deformer = MeshDeformer(hidden=32, num_blocks=1, rings=5, segments=6)
    b = batch(B=2, T=1)
    g = torch.Generator().manual_seed(1)
    p = torch.rand(500, 3, generator=g) * 2 - 1
    axis = torch.randint(0, 3, (500,), generator=g)
    p[torch.arange(500), axis] = torch.sign(p[torch.arange(500), axis])
    cube = p * 0.3 + torch.tensor([-0.25, 0.15, 1.9])
    sphere = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1) * 0.3 + torch.tensor(
        [0.3, -0.2, 2.2]
    )
    gt = torch.stack([cube, sphere])
    normals = torch.nn.functional.normalize(gt - gt.mean(1, keepdim=True), dim=-1)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    first = last = None
    for _ in range(60):
        terms = mesh_loss_terms(run(net, b), gt, normals)
        opt.zero_grad()
        terms["loss"].backward()
        opt.step()
        last = terms["chamfer_final"].item()
        first = last if first is None else first
    assert last <= 0.1 * first, f"chamfer {first:.4f} -> {last:.4f}"
