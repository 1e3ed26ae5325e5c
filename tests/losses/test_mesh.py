"""Pixel2Mesh mesh losses against naive python-loop references."""

import math

import pytest
import torch

from tvrecon.losses.chamfer import chamfer_terms
from tvrecon.losses.mesh import (
    DEFAULT_WEIGHTS,
    MeshLoss,
    edge_length_loss,
    laplacian_coordinates,
    laplacian_loss,
    mesh_loss_terms,
    move_loss,
    normal_loss,
)
from tvrecon.models.components.ellipsoid import mesh_edges

# a tetrahedron
FACES = torch.tensor([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
EDGES = mesh_edges(FACES)


def naive_neighbours(edges: torch.Tensor, v: int) -> list[int]:
    out = []
    for a, b in edges.tolist():
        if a == v:
            out.append(b)
        elif b == v:
            out.append(a)
    return out


def naive_laplacian(verts: list[list[float]], edges: torch.Tensor) -> list[list[float]]:
    lap = []
    for v, p in enumerate(verts):
        nb = naive_neighbours(edges, v)
        mean = [sum(verts[n][k] for n in nb) / len(nb) for k in range(3)]
        lap.append([p[k] - mean[k] for k in range(3)])
    return lap


def test_edge_length_loss_matches_naive() -> None:
    verts = torch.rand(2, 4, 3)
    got = edge_length_loss(verts, EDGES, reduction="none")
    for b in range(2):
        v = verts[b].tolist()
        ref = sum(sum((v[i][k] - v[j][k]) ** 2 for k in range(3)) for i, j in EDGES.tolist()) / len(EDGES)
        assert got[b].item() == pytest.approx(ref, rel=1e-5)


def test_laplacian_matches_naive_and_change_form() -> None:
    verts, before = torch.rand(2, 4, 3), torch.rand(2, 4, 3)
    lap = laplacian_coordinates(verts, EDGES)
    for b in range(2):
        ref = naive_laplacian(verts[b].tolist(), EDGES)
        assert torch.allclose(lap[b], torch.tensor(ref), atol=1e-6)
    got = laplacian_loss(verts, EDGES, reduction="none")
    got_change = laplacian_loss(verts, EDGES, before=before, reduction="none")
    for b in range(2):
        la = naive_laplacian(verts[b].tolist(), EDGES)
        lb = naive_laplacian(before[b].tolist(), EDGES)
        ref = sum(sum(c * c for c in row) for row in la) / 4
        ref_change = sum(sum((la[i][k] - lb[i][k]) ** 2 for k in range(3)) for i in range(4)) / 4
        assert got[b].item() == pytest.approx(ref, rel=1e-5)
        assert got_change[b].item() == pytest.approx(ref_change, rel=1e-5)
    # translation does not change the Laplacian change
    assert laplacian_loss(before + 1.0, EDGES, before=before).item() == pytest.approx(0.0, abs=1e-10)


def test_move_loss_matches_naive() -> None:
    a, b = torch.rand(2, 4, 3), torch.rand(2, 4, 3)
    got = move_loss(a, b, reduction="sum")
    ref = sum(
        sum(sum((a[s, i, k].item() - b[s, i, k].item()) ** 2 for k in range(3)) for i in range(4)) / 4 for s in range(2)
    )
    assert got.item() == pytest.approx(ref, rel=1e-5)


def test_normal_loss_matches_naive() -> None:
    verts = torch.rand(2, 4, 3)
    gt = torch.rand(2, 9, 3)
    normals = torch.nn.functional.normalize(torch.randn(2, 9, 3), dim=-1)
    idx = chamfer_terms(verts, gt).idx_xy
    got = normal_loss(verts, EDGES, normals, idx, reduction="none")
    for b in range(2):
        v, n = verts[b].tolist(), normals[b].tolist()
        total = 0.0
        for i, j in EDGES.tolist():
            e = [v[i][k] - v[j][k] for k in range(3)]
            en = math.sqrt(sum(c * c for c in e))
            nn_ = n[idx[b, i].item()]
            total += abs(sum(e[k] * nn_[k] for k in range(3)) / en)
        assert got[b].item() == pytest.approx(total / len(EDGES), rel=1e-5)


def test_normal_loss_zero_for_tangent_edges() -> None:
    # a flat square in z = 0 with +z normals: every edge is tangent
    verts = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]])
    edges = torch.tensor([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])
    normals = torch.tensor([[[0.0, 0, 1]] * 4])
    assert normal_loss(verts, edges, normals, torch.arange(4)[None]).item() == pytest.approx(0.0, abs=1e-7)


def _fake_output(num_stages: int = 2) -> dict:
    verts = [torch.rand(2, 4, 3, requires_grad=True) for _ in range(num_stages)]
    before = [torch.rand(2, 4, 3) for _ in range(num_stages)]
    return {"verts": verts, "verts_before": before, "edges": [EDGES] * num_stages}


def test_mesh_loss_terms_weighted_total() -> None:
    out = _fake_output(2)
    gt, normals = torch.rand(2, 10, 3), torch.nn.functional.normalize(torch.randn(2, 10, 3), dim=-1)
    w = {"chamfer": 1.0, "normal": 0.1, "edge": 0.2, "laplace": 0.3, "move": 0.4}
    terms = mesh_loss_terms(out, gt, normals, w, stage_weights=[1.0, 2.0], laplacian_stage_weights=(0.5, 1.0))
    expected = 0.0
    for s, sw in enumerate([1.0, 2.0]):
        v, vb = out["verts"][s], out["verts_before"][s]
        ch = chamfer_terms(v, gt)
        stage = (
            1.0 * ch.loss
            + 0.1 * normal_loss(v, EDGES, normals, ch.idx_xy)
            + 0.2 * edge_length_loss(v, EDGES)
            + 0.3 * (0.5 if s == 0 else 1.0) * laplacian_loss(v, EDGES, before=vb)
            + (0.4 * move_loss(v, vb) if s >= 1 else 0.0)
        )
        expected = expected + sw * stage
    assert terms["loss"].item() == pytest.approx(expected.item(), rel=1e-5)
    assert set(terms) == {"chamfer", "normal", "edge", "laplacian", "move", "chamfer_final", "loss"}
    terms["loss"].backward()
    assert all(v.grad is not None and v.grad.abs().sum() > 0 for v in out["verts"])


def test_mesh_loss_defaults_and_zero_weights() -> None:
    assert DEFAULT_WEIGHTS == {"chamfer": 1.0, "normal": 1.6e-4, "edge": 0.1, "laplacian": 0.5, "move": 0.033}
    out = _fake_output(3)
    gt, normals = torch.rand(2, 10, 3), torch.rand(2, 10, 3)
    only_chamfer = MeshLoss({"normal": 0, "edge": 0, "laplacian": 0, "move": 0})(out, gt, normals)
    ref = sum(chamfer_terms(v, gt).loss for v in out["verts"])
    assert only_chamfer["loss"].item() == pytest.approx(ref.item(), rel=1e-6)
    assert only_chamfer["edge"].item() == 0.0
    with pytest.raises(ValueError, match="unknown loss weight"):
        MeshLoss({"chamfr": 1.0})
    with pytest.raises(ValueError, match="one weight per stage"):
        mesh_loss_terms(out, gt, normals, stage_weights=[1.0])


def test_mesh_losses_name_a_bad_shape() -> None:
    v = torch.rand(2, 4, 3)
    with pytest.raises(ValueError, match=r"verts must have shape \(B, V, 3\), got \(4, 3\)"):
        edge_length_loss(v[0], EDGES)
    with pytest.raises(ValueError, match=r"edges must have shape \(E, 2\), got \(6,\)"):
        laplacian_coordinates(v, EDGES[:, 0])
    with pytest.raises(ValueError, match=r"verts must have shape \(B, V, 3\), got \(2, 4, 2\)"):
        move_loss(v[..., :2], v[..., :2])
    with pytest.raises(ValueError, match=r"before must have the shape of verts \(2, 4, 3\), got \(1, 4, 3\)"):
        move_loss(v, v[:1])
    idx = torch.zeros(2, 4, dtype=torch.long)
    with pytest.raises(ValueError, match=r"gt_normals must have shape \(B, M, 3\), got \(5, 3\)"):
        normal_loss(v, EDGES, torch.rand(5, 3), idx)
    with pytest.raises(ValueError, match=r"gt_normals must have shape \(B, M, 3\) with B=2, got \(1, 5, 3\)"):
        normal_loss(v, EDGES, torch.rand(1, 5, 3), idx)
    out = _fake_output(3)
    with pytest.raises(ValueError, match=r"normals must have the shape of points \(2, 10, 3\), got \(2, 9, 3\)"):
        mesh_loss_terms(out, torch.rand(2, 10, 3), torch.rand(2, 9, 3))
