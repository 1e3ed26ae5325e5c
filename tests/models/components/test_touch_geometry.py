"""Touch-geometry model (beyond the paper): patch point selection, per-vertex touch features, the deformer reading
them, the patch training term, and that a tiny batch is overfit only when the patches are real."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.touch_geometry import (
    TouchGeometryDeformer,
    TouchGeometryReconstructor,
    TouchPoints,
    patch_to_mesh_loss,
    select_patch_points,
    touch_features,
)


def _camera(B: int, H: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    f = 0.5 * H / math.tan(math.radians(35.0) / 2)
    K = torch.tensor([[f, 0.0, (H - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]]).expand(B, 3, 3)
    RT = torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], dim=1).expand(B, 3, 4)
    return K.contiguous(), RT.contiguous()


def _patches(
    B: int, T: int, Q: int, seed: int = 0, radius: float = 0.3
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    d = F.normalize(torch.randn(B, T, 1, 3, generator=g), dim=-1)
    pts = F.normalize(d + 0.1 * torch.randn(B, T, Q, 3, generator=g), dim=-1) * radius  # (B, T, Q, 3) on a sphere
    return pts, F.normalize(pts, dim=-1), torch.rand(B, T, Q, generator=g) < 0.4


def _small_net(seed: int = 0) -> TouchGeometryReconstructor:
    torch.manual_seed(seed)
    return TouchGeometryReconstructor(deformer=TouchGeometryDeformer(hidden=16, num_blocks=1))


def fit_patch_term(
    net: torch.nn.Module,
    image: torch.Tensor,
    K: torch.Tensor,
    RT: torch.Tensor,
    patches: dict[str, torch.Tensor],
    steps: int = 60,
    lr: float = 3e-3,
) -> None:
    """``steps`` Adam steps on the patch term of the last stage's mesh (the overfit tests)."""
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    for _ in range(steps):
        out = net(image, K, RT, **patches)
        loss = patch_to_mesh_loss(out["verts"][-1], out["touch"])
        opt.zero_grad()
        loss.backward()
        opt.step()


def test_select_patch_points_keeps_contact_points_evenly() -> None:
    B, T, Q = 2, 3, 50
    pts = torch.arange(B * T * Q, dtype=torch.float32).reshape(B, T, Q, 1).expand(-1, -1, -1, 3).contiguous()
    mask = torch.zeros(B, T, Q, dtype=torch.bool)
    mask[0, 0, 10:40] = True  # 30 contact points, more than m = 8
    mask[0, 1, 5:8] = True  # 3, fewer than m
    mask[1, 2, :] = True
    touch_mask = torch.tensor([[True, True, True], [True, True, False]])
    sel = select_patch_points(pts, pts, mask, touch_mask, per_touch=8)
    assert sel.points.shape == (B, T * 8, 3) and sel.mask.shape == (B, T * 8)
    counts = sel.mask.reshape(B, T, 8).sum(-1)
    assert counts.tolist() == [[8, 3, 0], [0, 0, 0]]  # the third touch of sample 1 is not used
    first = sel.points[0, :8, 0] - pts[0, 0, 0, 0]  # pad indices of the chosen points
    assert first.tolist() == [10 + 30 * j // 8 for j in range(8)]  # spread over the 30 contact points
    assert (sel.points[0, 8:11, 0] - pts[0, 1, 0, 0]).tolist() == [5, 6, 7]


def test_touch_features_single_point_and_no_point() -> None:
    verts = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])  # (2, 2, 3)
    p = torch.tensor([[[0.1, 0.0, 0.0], [9.0, 9.0, 9.0]], [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    n = torch.tensor([[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]]).expand(2, -1, -1)
    mask = torch.tensor([[True, False], [False, False]])  # sample 0: one real point, sample 1: none
    feats = touch_features(verts, TouchPoints(p, n, mask), sigmas=[0.1, 1.0])
    assert feats.shape == (2, 2, 14)
    for s, sigma in enumerate([0.1, 1.0]):
        f = feats[0, :, 7 * s : 7 * s + 7]
        torch.testing.assert_close(f[:, :3], p[0, :1] - verts[0])  # offset to the only point, near or far
        torch.testing.assert_close(f[:, 3:6], n[0, :1].expand(2, 3))
        w = torch.exp(-((p[0, 0] - verts[0]) ** 2).sum(-1) / (2 * sigma**2))
        torch.testing.assert_close(f[:, 6], 1 - torch.exp(-w))
    assert torch.equal(feats[1], torch.zeros(2, 14))  # no contact: every feature zero
    assert torch.isfinite(feats).all()


def test_touch_features_bad_input() -> None:
    touch = TouchPoints(torch.zeros(1, 2, 3), torch.zeros(1, 2, 3), torch.ones(1, 2, dtype=torch.bool))
    with pytest.raises(ValueError, match="sigmas"):
        touch_features(torch.zeros(1, 4, 3), touch, sigmas=[0.0])
    with pytest.raises(ValueError, match="must match B"):
        touch_features(torch.zeros(2, 4, 3), touch, sigmas=[0.1])


def test_patch_to_mesh_loss() -> None:
    verts = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]], requires_grad=True)
    pts = torch.tensor([[[0.0, 0.5, 0.0], [1.0, 0.0, 0.2], [5.0, 5.0, 5.0]]])
    touch = TouchPoints(pts, pts, torch.tensor([[True, True, False]]))
    loss = patch_to_mesh_loss(verts, touch)
    assert loss.item() == pytest.approx((0.25 + 0.04) / 2)
    loss.backward()
    assert verts.grad is not None and verts.grad.abs().sum() > 0
    none = TouchPoints(pts, pts, torch.zeros(1, 3, dtype=torch.bool))
    assert patch_to_mesh_loss(verts, none).item() == 0.0


def test_model_shapes_zero_to_ten_touches_and_reads_patches() -> None:
    B, T, Q = 2, 10, 40
    net = _small_net().eval()
    K, RT = _camera(B)
    image = torch.rand(B, 3, 64, 64)
    pts, nrm, pmask = _patches(B, T, Q)
    none = net(image, K, RT)
    assert none["verts"][-1].shape == (B, 2466, 3) and none["touch"] is None
    zero = net(
        image,
        K,
        RT,
        touch_mask=torch.zeros(B, T, dtype=torch.bool),
        patch_points=pts,
        patch_normals=nrm,
        patch_mask=pmask,
    )
    torch.testing.assert_close(zero["verts"][-1], none["verts"][-1])  # 0 touches == no touch input
    touch_mask = torch.arange(T)[None] < torch.tensor([[3], [10]])  # 3 and 10 touches
    out = net(image, K, RT, touch_mask=touch_mask, patch_points=pts, patch_normals=nrm, patch_mask=pmask)
    assert out["touch"].points.shape == (B, T * 64 if Q >= 64 else T * Q, 3)
    assert (out["verts"][-1] - none["verts"][-1]).abs().max() > 1e-6  # the patches change the mesh
    other = net(
        image,
        K,
        RT,
        touch_mask=touch_mask,
        patch_points=pts.roll(1, 0),
        patch_normals=nrm.roll(1, 0),
        patch_mask=pmask.roll(1, 0),
    )
    assert (out["verts"][-1] - other["verts"][-1]).abs().max() > 1e-6  # other patches, other mesh
    with pytest.raises(ValueError, match="together"):
        net(image, K, RT, patch_points=pts)
    with pytest.raises(ValueError, match="no tactile branch"):
        TouchGeometryReconstructor(tactile_backbone=ResNet18Backbone())


def test_gradient_reaches_touch_layers() -> None:
    B, T, Q = 2, 4, 30
    net = _small_net()
    K, RT = _camera(B)
    pts, nrm, pmask = _patches(B, T, Q)
    out = net(torch.rand(B, 3, 64, 64), K, RT, patch_points=pts, patch_normals=nrm, patch_mask=pmask)
    loss = sum(patch_to_mesh_loss(v, out["touch"]) for v in out["verts"])
    loss.backward()
    for s, stage in enumerate(net.deformer.stages):
        assert stage.touch_in[0].weight.grad is not None and stage.touch_in[0].weight.grad.abs().sum() > 0, s
    assert net.visual.stem[0].weight.grad is not None


def test_overfits_patch_term_with_real_patches_only() -> None:
    """A few Adam steps bring the mesh onto one object's patches; the learned network uses them: fed the patches of
    another object (a smaller sphere; same image), the same network misses the first object's patches by much
    more. A network that ignored its patches would give the same mesh, and the same loss, for both."""
    B, T, Q = 1, 6, 40
    net = _small_net(seed=1)
    K, RT = _camera(B)
    image = torch.rand(B, 3, 64, 64)
    pts, nrm, pmask = _patches(1, T, Q, seed=3)
    other_pts, other_nrm, other_mask = _patches(1, T, Q, seed=4, radius=0.15)
    own = {"patch_points": pts, "patch_normals": nrm, "patch_mask": pmask}
    fit_patch_term(net, image, K, RT, own)
    with torch.no_grad():
        fit = net(image, K, RT, **own)
        target = fit["touch"]
        swapped = net(image, K, RT, patch_points=other_pts, patch_normals=other_nrm, patch_mask=other_mask)
        own_loss = patch_to_mesh_loss(fit["verts"][-1], target).item()
        swapped_loss = patch_to_mesh_loss(swapped["verts"][-1], target).item()
    assert own_loss < 2e-3
    assert swapped_loss > 3 * own_loss


def test_view_pass_is_the_no_touch_answer_in_training_only() -> None:
    """``view_pass``: in training the output also holds the same network's answer without touches (on the same image
    features), which a loss can train on every sample; in eval one pass, as without the option."""
    B, T, Q = 2, 4, 30
    torch.manual_seed(0)
    net = TouchGeometryReconstructor(deformer=TouchGeometryDeformer(hidden=16, num_blocks=1), view_pass=True)
    K, RT = _camera(B)
    image = torch.rand(B, 3, 64, 64)
    pts, nrm, pmask = _patches(B, T, Q)
    net.eval()  # BatchNorm in eval: the same features in both calls
    with torch.no_grad():
        none = net(image, K, RT)
        touched = net(image, K, RT, patch_points=pts, patch_normals=nrm, patch_mask=pmask)
    assert "visual" not in none and "visual" not in touched
    net.train()
    net.visual.eval()  # the backbone's BatchNorm as above, so both passes read the features the eval calls read
    out = net(image, K, RT, patch_points=pts, patch_normals=nrm, patch_mask=pmask)
    assert "visual" in out
    torch.testing.assert_close(out["visual"]["verts"][-1], none["verts"][-1])  # the view pass = no touch
    torch.testing.assert_close(out["verts"][-1], touched["verts"][-1])  # the touched pass is unchanged
    assert (out["verts"][-1] - out["visual"]["verts"][-1]).abs().max() > 1e-6
    loss = out["visual"]["verts"][-1].square().mean()
    loss.backward()  # the view pass's loss trains the shared backbone and deformer
    assert net.visual.stem[0].weight.grad is not None and net.visual.stem[0].weight.grad.abs().sum() > 0
    assert net.deformer.stages[-1].conv_out.self_linear.weight.grad.abs().sum() > 0
    no_touch = net(image, K, RT)
    assert "visual" not in no_touch  # a batch without touches is its own view pass


def test_view_pass_needs_touch_geometrys_own_deformer() -> None:
    from tvrecon.models.components.touch_residual import TouchResidualDeformer

    with pytest.raises(ValueError, match="view_pass"):
        TouchGeometryReconstructor(deformer=TouchResidualDeformer(hidden=16, num_blocks=1), view_pass=True)
