"""Test-time touch refinement (tvrecon.models.refine)."""

from __future__ import annotations

import pytest
import torch

from tvrecon.losses.metrics import chamfer_metric
from tvrecon.models.components.ellipsoid import EllipsoidTemplate
from tvrecon.models.refine import refine_to_patches


@pytest.fixture(scope="module")
def too_flat():
    """A predicted ellipsoid whose true shape is 1.4x deeper along the camera axis, and patches on its hidden side."""
    t = EllipsoidTemplate(3, (0.35, 0.35, 0.25), 2.0, 11, 14)
    v, f, e = t.verts(2), t.faces(2), t.edges(2)
    c = v.mean(0)
    gt = (v - c) * torch.tensor([1.0, 1.0, 1.4]) + c
    far = gt[(gt[:, 2] - c[2]) > 0.15]  # behind the object, away from the camera
    pts = far[torch.randperm(len(far), generator=torch.Generator().manual_seed(0))[:300]]
    return v[None], f, e, gt[None], pts[None]


def test_refinement_pulls_the_mesh_onto_hidden_patches(too_flat):
    verts, faces, edges, gt, pts = too_flat
    mask = torch.ones(pts.shape[:2], dtype=torch.bool)
    before = float(chamfer_metric(verts, faces, gt))
    with torch.inference_mode():  # as under Lightning's test loop
        refined = refine_to_patches(verts, edges, pts, mask)
    after = float(chamfer_metric(refined, faces, gt))
    assert after < 0.7 * before  # measured 6.53 -> 3.60
    # the camera-facing side (no patch there) barely moves: the deformation is local and smooth
    c = verts[0].mean(0)
    front = (verts[0, :, 2] - c[2]) < -0.1
    assert float((refined[0, front] - verts[0, front]).norm(dim=-1).max()) < 0.02


def test_no_contact_points_leave_the_mesh_unchanged(too_flat):
    verts, _, edges, _, pts = too_flat
    mask = torch.zeros(pts.shape[:2], dtype=torch.bool)
    assert torch.equal(refine_to_patches(verts, edges, pts, mask), verts)
    # a batch where one sample has points and one has none: the empty one stays put
    both = refine_to_patches(
        verts.expand(2, -1, -1),
        edges,
        pts.expand(2, -1, -1),
        torch.tensor([[True] * pts.shape[1], [False] * pts.shape[1]]),
    )
    assert torch.allclose(both[1], verts[0], atol=1e-6) and not torch.allclose(both[0], verts[0], atol=1e-3)


def test_bad_input_is_named(too_flat):
    verts, _, edges, _, pts = too_flat
    with pytest.raises(ValueError, match="mask must be"):
        refine_to_patches(verts, edges, pts, torch.ones(1, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"points must have shape \(B, N, 3\), got \(300, 3\)"):
        refine_to_patches(verts, edges, pts[0], torch.ones(1, 300, dtype=torch.bool))
