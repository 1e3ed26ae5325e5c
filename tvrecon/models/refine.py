"""Test-time touch refinement (beyond the paper): deform a predicted mesh smoothly so the contact patches lie on it.

Every contact-patch point (:func:`tvrecon.sim.sensor.patch.contact_patch`, mapped to the camera frame) is a sample of
the true surface, often on the side the camera cannot see. Refinement optimises per-vertex offsets ``delta`` of the
predicted mesh for a few Adam steps on::

    mean_p |p - nearest vertex(v + delta)|^2  +  laplacian_weight * mean_v |L(v + delta) - L(v)|^2

(the Pixel2Mesh Laplacian-change term of :func:`tvrecon.losses.mesh.laplacian_loss` keeps the deformation smooth, so
the vertices the patches pull drag their neighbourhood along). A sample without contact points is returned as it
was. It works on any model's prediction, the visual-only baseline included.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tvrecon.losses.chamfer import nearest_neighbors
from tvrecon.losses.mesh import laplacian_loss
from tvrecon.utils.shape_check import check_shape

__all__ = ["refine_to_patches"]


def refine_to_patches(
    verts: Tensor,
    edges: Tensor,
    points: Tensor,
    mask: Tensor,
    steps: int = 40,
    lr: float = 5e-3,
    laplacian_weight: float = 5.0,
) -> Tensor:
    """Pull a predicted mesh onto contact-patch points.

    Args:
        verts: (B, V, 3) float predicted vertices (camera frame).
        edges: (E, 2) int64 undirected edges of the mesh.
        points: (B, N, 3) float contact points in the same frame as ``verts``.
        mask: (B, N) bool, True for real contact points (padding and non-contact points False).
        steps: Adam steps.
        lr: Adam learning rate (world units per step, roughly).
        laplacian_weight: weight of the Laplacian-change smoothness term.

    Returns:
        (B, V, 3) float refined vertices (no gradient).
    """
    check_shape(verts, "(B, V, 3)", "verts")
    B = verts.shape[0]
    check_shape(points, "(B, N, 3)", "points")
    if points.shape[0] != B:
        raise ValueError(f"points must have shape (B, N, 3) with B={B} like verts, got {tuple(points.shape)}")
    if mask.shape != points.shape[:2] or mask.dtype != torch.bool:
        raise ValueError(f"mask must be a {tuple(points.shape[:2])} bool tensor, got {tuple(mask.shape)} {mask.dtype}")
    if int(steps) < 0 or not float(lr) > 0 or not float(laplacian_weight) >= 0:
        raise ValueError(f"need steps >= 0, lr > 0, laplacian_weight >= 0; got {steps}, {lr}, {laplacian_weight}")
    if int(steps) == 0 or not bool(mask.any()):
        return verts.detach().clone()
    # Lightning tests under inference mode: work on normal tensors with autograd on, whatever the caller's mode
    with torch.inference_mode(False), torch.enable_grad():
        v0 = verts.detach().clone().float()
        pts = points.detach().clone().float()
        m = mask.detach().clone().float()  # (B, N)
        count = m.sum(1).clamp_min(1.0)  # (B,)
        delta = torch.zeros_like(v0, requires_grad=True)
        opt = torch.optim.Adam([delta], lr=float(lr))
        for _ in range(int(steps)):
            v = v0 + delta
            dist, _ = nearest_neighbors(pts, v)  # (B, N) squared distance of each point to its nearest vertex
            data = (dist * m).sum(1) / count  # (B,)
            smooth = laplacian_loss(v, edges, before=v0, reduction="none")  # (B,)
            loss = (data + float(laplacian_weight) * smooth).sum()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        out = (v0 + delta).detach()
    return out.to(verts.dtype)
