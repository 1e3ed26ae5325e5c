"""Evaluation metrics: seeded area-weighted surface sampling, chamfer x 1e-3 and F-score.

Units: points are in the scene's length unit (objects are normalised to max extent 1). ``chamfer_metric`` returns the
chamfer distance (squared distances, mean each way, summed) multiplied by 1000, i.e. the number printed in the paper's
tables "(x 10^-3)". ``fscore`` thresholds are plain (not squared) Euclidean DISTANCES in that unit; the defaults
tau = 0.01 and 2 tau = 0.02 follow Pixel2Mesh's F-score at tau and 2 tau (Pixel2Mesh states tau = 1e-4 on squared
distances, i.e. 0.01 in distance; its "2 tau" is squared too, so our 0.02 is slightly stricter than its sqrt(2e-4)).
F-scores are fractions in [0, 1] (multiply by 100 for percent).

``chamfer_metric`` / ``fscore`` take the predicted MESH (verts, faces) and the GT points; ``*_points`` variants take
two point clouds.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from tvrecon.losses.chamfer import chamfer_terms
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "DEFAULT_FSCORE_THRESHOLDS",
    "chamfer_metric",
    "chamfer_metric_points",
    "fscore",
    "fscore_points",
    "sample_points_on_mesh",
]

DEFAULT_FSCORE_THRESHOLDS: tuple[float, float] = (0.01, 0.02)


def sample_points_on_mesh(
    verts: Tensor, faces: Tensor, n: int = 1000, seed: int | torch.Generator = 0
) -> tuple[Tensor, Tensor]:
    """Sample points uniformly by area on triangle meshes sharing one connectivity (seeded, batched).

    Args:
        verts: (B, V, 3) or (V, 3) float vertices.
        faces: (F, 3) int64.
        n: points per mesh.
        seed: int seed or a ``torch.Generator`` on the vertices' device.

    Returns:
        points (B, n, 3) float and face_index (B, n) int64 of the face each point lies on ((n, 3), (n,) for unbatched
        input). Degenerate meshes (zero total area) sample faces uniformly.
    """
    check_shape(verts, "(B, V, 3) or (V, 3)", "verts")
    check_shape(faces, "(F, 3)", "faces")
    unbatched = verts.dim() == 2
    if unbatched:
        verts = verts[None]
    if faces.shape[0] == 0:
        raise ValueError(f"faces must have shape (F, 3) with F > 0, got {tuple(faces.shape)}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if isinstance(seed, torch.Generator):
        gen = seed
    else:
        gen = torch.Generator(device=verts.device)
        gen.manual_seed(int(seed))
    tri = verts[:, faces]  # (B, F, 3, 3)
    a, b, c = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    areas = 0.5 * torch.linalg.cross(b - a, c - a).norm(dim=-1)  # (B, F)
    probs = areas.detach().clone()
    flat = probs.sum(1, keepdim=True) <= 0
    probs = torch.where(flat, torch.ones_like(probs), probs)
    face_idx = torch.multinomial(probs, n, replacement=True, generator=gen)  # (B, n)
    r = torch.rand(verts.shape[0], n, 2, generator=gen, device=verts.device, dtype=verts.dtype)
    s = r[..., 0:1].sqrt()
    w0, w1, w2 = 1 - s, s * (1 - r[..., 1:2]), s * r[..., 1:2]

    def pick(x: Tensor) -> Tensor:
        return torch.gather(x, 1, face_idx[..., None].expand(-1, -1, 3))

    points = w0 * pick(a) + w1 * pick(b) + w2 * pick(c)  # (B, n, 3)
    if unbatched:
        return points[0], face_idx[0]
    return points, face_idx


def _sample_pair(verts: Tensor, faces: Tensor, gt_points: Tensor, num_samples: int, seed: int) -> tuple[Tensor, Tensor]:
    """Seeded area-weighted samples on the prediction and a seeded subsample of the GT cloud (both (B, n, 3))."""
    check_shape(verts, "(B, V, 3)", "verts")
    check_shape(gt_points, "(B, M, 3)", "gt_points")
    if gt_points.shape[0] != verts.shape[0]:
        raise ValueError(f"gt_points must have shape (B, M, 3) with B={verts.shape[0]}, got {tuple(gt_points.shape)}")
    gen = torch.Generator(device=verts.device)
    gen.manual_seed(int(seed))
    pred, _ = sample_points_on_mesh(verts, faces, num_samples, gen)
    if gt_points.shape[1] > num_samples:
        idx = torch.stack(
            [
                torch.randperm(gt_points.shape[1], generator=gen, device=verts.device)[:num_samples]
                for _ in range(gt_points.shape[0])
            ]
        )  # (B, n)
        gt_points = torch.gather(gt_points, 1, idx[..., None].expand(-1, -1, 3))
    return pred, gt_points.to(pred.dtype)


def chamfer_metric_points(
    pred_points: Tensor, gt_points: Tensor, pred_lengths: Tensor | None = None, gt_lengths: Tensor | None = None
) -> Tensor:
    """Chamfer distance x 1000 per sample between two point clouds (the paper's table unit).

    Args:
        pred_points: (B, N, 3) float; gt_points: (B, M, 3) float (same frame).
        pred_lengths, gt_lengths: (B,) int64 valid points (None = all).

    Returns:
        (B,) float.
    """
    return chamfer_terms(pred_points, gt_points, pred_lengths, gt_lengths, reduction="none").loss * 1e3


def chamfer_metric(verts: Tensor, faces: Tensor, gt_points: Tensor, num_samples: int = 1000, seed: int = 0) -> Tensor:
    """Paper metric: chamfer x 1e-3 between ``num_samples`` seeded area-weighted samples of the predicted mesh and of
    the GT surface.

    GT clouds with more than ``num_samples`` points are subsampled to ``num_samples`` with the same seed (the dataset's
    GT points are already area-weighted surface samples).

    Args:
        verts: (B, V, 3) float predicted vertices; faces: (F, 3) int64.
        gt_points: (B, M, 3) float GT surface points in the same frame.
        num_samples: points per surface (1,000 in the paper).
        seed: sampling seed (the metric is deterministic for a given seed).

    Returns:
        (B,) float chamfer x 1000.
    """
    pred, gt = _sample_pair(verts, faces, gt_points, num_samples, seed)
    return chamfer_metric_points(pred, gt)


def fscore_points(
    pred_points: Tensor,
    gt_points: Tensor,
    thresholds: float | Sequence[float] = DEFAULT_FSCORE_THRESHOLDS,
    pred_lengths: Tensor | None = None,
    gt_lengths: Tensor | None = None,
) -> Tensor:
    """F-score between point clouds at distance thresholds.

    precision = fraction of predicted points whose nearest GT point is closer than ``tau`` (Euclidean distance,
    strict ``<``), recall = fraction of GT points closer than ``tau`` to the prediction, F = 2PR / (P + R) (0 when
    P + R = 0).

    Args:
        pred_points: (B, N, 3) float; gt_points: (B, M, 3) float.
        thresholds: one distance or a sequence of distances (same unit as the points).
        pred_lengths, gt_lengths: (B,) int64 valid points (None = all).

    Returns:
        (B,) float in [0, 1] for a single threshold, (B, K) for K thresholds.
    """
    single = isinstance(thresholds, (int, float))
    taus = [float(thresholds)] if single else [float(t) for t in thresholds]
    if len(taus) == 0 or min(taus) <= 0:
        raise ValueError(f"thresholds must be positive distances, got {thresholds}")
    res = chamfer_terms(pred_points, gt_points, pred_lengths, gt_lengths, reduction="none")
    B, N, M = pred_points.shape[0], pred_points.shape[1], gt_points.shape[1]
    pm = torch.ones(B, N, dtype=torch.bool, device=pred_points.device)
    gm = torch.ones(B, M, dtype=torch.bool, device=gt_points.device)
    if pred_lengths is not None:
        pm = torch.arange(N, device=pm.device)[None] < pred_lengths.to(pm.device)[:, None]
    if gt_lengths is not None:
        gm = torch.arange(M, device=gm.device)[None] < gt_lengths.to(gm.device)[:, None]
    out = []
    for tau in taus:
        p = ((res.dist_xy < tau * tau) & pm).sum(1) / pm.sum(1)
        r = ((res.dist_yx < tau * tau) & gm).sum(1) / gm.sum(1)
        denom = p + r
        out.append(torch.where(denom > 0, 2 * p * r / denom.clamp(min=1e-12), torch.zeros_like(denom)))
    result = torch.stack(out, dim=1).to(pred_points.dtype)
    return result[:, 0] if single else result


def fscore(
    verts: Tensor,
    faces: Tensor,
    gt_points: Tensor,
    thresholds: float | Sequence[float] = DEFAULT_FSCORE_THRESHOLDS,
    num_samples: int = 1000,
    seed: int = 0,
) -> Tensor:
    """F-score of predicted meshes against GT surface points, on the same seeded samples as ``chamfer_metric``.

    Args:
        verts: (B, V, 3) float; faces: (F, 3) int64; gt_points: (B, M, 3) float.
        thresholds: one distance or a sequence (default tau = 0.01 and 2 tau = 0.02, see module docstring).
        num_samples, seed: as in ``chamfer_metric``.

    Returns:
        (B,) float in [0, 1] for one threshold, (B, K) for K thresholds.
    """
    pred, gt = _sample_pair(verts, faces, gt_points, num_samples, seed)
    return fscore_points(pred, gt, thresholds)
