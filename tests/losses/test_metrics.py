"""Sampling, chamfer x 1e-3 and F-score against naive references."""

import math

import pytest
import torch
import trimesh

from tvrecon.losses.metrics import (
    chamfer_metric,
    chamfer_metric_points,
    fscore,
    fscore_points,
    sample_points_on_mesh,
)


def test_sampling_is_seeded_on_surface_and_area_weighted() -> None:
    # two triangles in z=0: the first has 3x the area of the second
    verts = torch.tensor([[0.0, 0, 0], [3, 0, 0], [0, 2, 0], [10, 0, 0], [11, 0, 0], [10, 2, 0]])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    p1, f1 = sample_points_on_mesh(verts[None].repeat(2, 1, 1), faces, n=4000, seed=3)
    p2, _ = sample_points_on_mesh(verts[None].repeat(2, 1, 1), faces, n=4000, seed=3)
    assert p1.shape == (2, 4000, 3) and torch.equal(p1, p2)
    p3, _ = sample_points_on_mesh(verts, faces, n=4000, seed=4)
    assert p3.shape == (4000, 3) and not torch.equal(p3, p1[0])
    assert (p1[..., 2] == 0).all()
    frac = (f1 == 0).float().mean().item()
    assert frac == pytest.approx(0.75, abs=0.03)
    # points lie inside their triangle (barycentric test)
    first = p1[0][f1[0] == 0]
    assert ((first[:, 0] >= -1e-6) & (first[:, 1] >= -1e-6) & (first[:, 0] / 3 + first[:, 1] / 2 <= 1 + 1e-5)).all()


def test_sampling_uniform_on_sphere_matches_trimesh_area() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = torch.tensor(mesh.vertices, dtype=torch.float32)
    f = torch.tensor(mesh.faces, dtype=torch.long)
    _, idx = sample_points_on_mesh(v, f, n=20000, seed=0)
    hist = torch.bincount(idx, minlength=len(f)).float() / 20000
    area = torch.tensor(mesh.area_faces / mesh.area, dtype=torch.float32)
    assert torch.allclose(hist.sum(), torch.tensor(1.0))
    # per-face frequencies follow the area fraction (loose: 20k samples over 320 faces)
    assert (hist - area).abs().max() < 0.01


def naive_nn(a: list, b: list) -> list[float]:
    return [min(sum((p[k] - q[k]) ** 2 for k in range(3)) for q in b) for p in a]


def test_chamfer_metric_points_and_fscore_against_naive() -> None:
    x, y = torch.rand(2, 12, 3), torch.rand(2, 9, 3)
    cm = chamfer_metric_points(x, y)
    taus = (0.1, 0.3)
    fs = fscore_points(x, y, taus)
    assert fs.shape == (2, 2)
    for b in range(2):
        dxy, dyx = naive_nn(x[b].tolist(), y[b].tolist()), naive_nn(y[b].tolist(), x[b].tolist())
        ref = (sum(dxy) / len(dxy) + sum(dyx) / len(dyx)) * 1000
        assert cm[b].item() == pytest.approx(ref, rel=1e-5)
        for t, tau in enumerate(taus):
            p = sum(d < tau**2 for d in dxy) / len(dxy)
            r = sum(d < tau**2 for d in dyx) / len(dyx)
            f = 0.0 if p + r == 0 else 2 * p * r / (p + r)
            assert fs[b, t].item() == pytest.approx(f, abs=1e-6)
    assert fscore_points(x, y, 0.1).shape == (2,)
    assert torch.equal(fscore_points(x, x, 1e-3), torch.ones(2))


def test_mesh_metrics_perfect_and_shifted() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    v = torch.tensor(mesh.vertices, dtype=torch.float32)[None]
    f = torch.tensor(mesh.faces, dtype=torch.long)
    gt, _ = sample_points_on_mesh(v, f, n=5000, seed=11)
    same = chamfer_metric(v, f, gt, num_samples=1000, seed=0)
    shifted = chamfer_metric(v + torch.tensor([0.1, 0.0, 0.0]), f, gt, num_samples=1000, seed=0)
    assert same.shape == (1,)
    # 1000 vs 1000 random samples of the same surface (area pi): each way E[d^2] ~ area / (pi n) = 1e-3, so ~2 x 1e-3
    assert 1.0 < same.item() < 3.0
    assert shifted.item() > 3 * same.item()
    assert chamfer_metric(v, f, gt, seed=5).item() == chamfer_metric(v, f, gt, seed=5).item()
    fs = fscore(v, f, gt, (0.01, 0.05))
    assert fs.shape == (1, 2) and fs[0, 1] > 0.9 and fs[0, 0] < fs[0, 1]
    assert fscore(v + 1.0, f, gt, 0.05).item() == 0.0


def test_metrics_validate_input() -> None:
    with pytest.raises(ValueError, match=r"faces must have shape \(F, 3\) with F > 0"):
        sample_points_on_mesh(torch.rand(1, 4, 3), torch.zeros(0, 3, dtype=torch.long))
    with pytest.raises(ValueError, match=r"faces must have shape \(F, 3\), got \(1, 4\)"):
        sample_points_on_mesh(torch.rand(1, 4, 3), torch.zeros(1, 4, dtype=torch.long))
    with pytest.raises(ValueError, match=r"verts must have shape \(B, V, 3\) or \(V, 3\), got \(4, 2\)"):
        sample_points_on_mesh(torch.rand(4, 2), torch.tensor([[0, 1, 2]]))
    with pytest.raises(ValueError, match="positive distances"):
        fscore_points(torch.rand(1, 4, 3), torch.rand(1, 4, 3), (0.0,))
    with pytest.raises(ValueError, match=r"gt_points must have shape \(B, M, 3\) with B=2"):
        chamfer_metric(torch.rand(2, 4, 3), torch.tensor([[0, 1, 2]]), torch.rand(3, 5, 3))
    with pytest.raises(ValueError, match=r"gt_points must have shape \(B, M, 3\), got \(5, 3\)"):
        chamfer_metric(torch.rand(2, 4, 3), torch.tensor([[0, 1, 2]]), torch.rand(5, 3))
    assert math.isfinite(
        chamfer_metric(torch.rand(2, 4, 3), torch.tensor([[0, 1, 2]]), torch.rand(2, 5, 3)).sum().item()
    )
