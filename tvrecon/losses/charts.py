"""Losses of the Chart-based method (Smith et al., NeurIPS 2020).

* ``sampled_chamfer``: the authors' global loss, the chamfer distance between points sampled uniformly by area on the
  predicted charts and the ground-truth surface points (their code: 10,000 samples, one loss on the final charts).
  Charts of zero area (a touch chart not in use, collapsed to a point) receive no sample.
* ``touch_chart_loss``: the authors' touch-chart loss, the chamfer distance between the points a touch network
  predicts and the touch's exact local surface, per touch, over the touches with contact in both.
* ``ChartLoss``: the weighted total, ``chamfer`` + ``edge`` (mean squared edge length of the charts,
  :func:`tvrecon.losses.mesh.edge_length_loss`; the authors use it when they fit a touch chart, not in the global loss,
  so its default weight is 0) + ``touch_chart`` (when the network returns it).

The authors scale both chamfer terms by 9,000 for Adam; Adam is invariant to a constant factor of the loss (up to its
epsilon), so the weights here are 1.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

from tvrecon.losses.chamfer import chamfer_terms, nearest_neighbors
from tvrecon.losses.mesh import edge_length_loss
from tvrecon.losses.metrics import sample_points_on_mesh
from tvrecon.utils.shape_check import check_shape

__all__ = ["CHART_WEIGHTS", "ChartLoss", "sampled_chamfer", "touch_chart_loss"]

CHART_WEIGHTS: dict[str, float] = {"chamfer": 1.0, "edge": 0.0, "touch_chart": 1.0}


def sampled_chamfer(
    verts: Tensor, faces: Tensor, points: Tensor, num_samples: int = 2048, generator: torch.Generator | None = None
) -> Tensor:
    """Chamfer distance between area-uniform samples of the charts and the GT points (per sample, differentiable in
    ``verts``).

    Args:
        verts: (B, V, 3) float chart vertices; faces: (F, 3) int64.
        points: (B, M, 3) float GT surface points (same frame).
        num_samples: points sampled on each prediction.
        generator: random generator of the sampling (None: a fresh one seeded from torch's global generator).

    Returns:
        (B,) float.
    """
    check_shape(verts, "(B, V, 3)", "verts")
    check_shape(points, "(B, M, 3)", "points")
    if points.shape[0] != verts.shape[0]:
        raise ValueError(f"points must have shape (B, M, 3) with B={verts.shape[0]}, got {tuple(points.shape)}")
    if generator is None:
        generator = torch.Generator(device=verts.device)
        generator.manual_seed(int(torch.randint(0, 2**62, ())))
    samples, _ = sample_points_on_mesh(verts, faces, num_samples, generator)
    return chamfer_terms(samples, points.to(samples.dtype), reduction="none").loss


def touch_chart_loss(pred: Tensor, pred_mask: Tensor, target: Tensor, target_mask: Tensor) -> Tensor:
    """Masked chamfer distance between predicted and exact contact points, averaged over the touches that have
    contact points in both.

    Args:
        pred: (N, P, 3) float predicted points; pred_mask: (N, P) bool.
        target: (N, Q, 3) float exact contact points; target_mask: (N, Q) bool.

    Returns:
        0-dim float (0 with a gradient path when no touch qualifies).
    """
    check_shape(pred, "(N, P, 3)", "pred")
    check_shape(target, "(N, Q, 3)", "target")
    N = pred.shape[0]
    if target.shape[0] != N or pred_mask.shape != pred.shape[:2] or target_mask.shape != target.shape[:2]:
        raise ValueError(
            f"pred (N, P, 3), pred_mask (N, P), target (N, Q, 3), target_mask (N, Q) must agree, got "
            f"{tuple(pred.shape)}, {tuple(pred_mask.shape)}, {tuple(target.shape)}, {tuple(target_mask.shape)}"
        )
    both = pred_mask.any(1) & target_mask.any(1)  # (N,)
    if not bool(both.any()):
        return pred.sum() * 0.0
    pred, pred_mask, target, target_mask = pred[both], pred_mask[both], target[both], target_mask[both]
    d_pt, _ = nearest_neighbors(pred, target.to(pred.dtype), target_mask)  # (n, P)
    d_tp, _ = nearest_neighbors(target.to(pred.dtype), pred, pred_mask)  # (n, Q)
    pm, tm = pred_mask.to(pred.dtype), target_mask.to(pred.dtype)
    per_touch = (d_pt * pm).sum(1) / pm.sum(1) + (d_tp * tm).sum(1) / tm.sum(1)
    return per_touch.mean()


class ChartLoss(nn.Module):
    """The Chart-based method's training loss on a network output.

    Args:
        weights: overrides of :data:`CHART_WEIGHTS` (``chamfer``, ``edge``, ``touch_chart``).
        num_samples: points sampled on the predicted charts for the chamfer term.
    """

    def __init__(self, weights: Mapping[str, float] | None = None, num_samples: int = 2048) -> None:
        super().__init__()
        merged = dict(CHART_WEIGHTS)
        for key, value in (weights or {}).items():
            if key not in CHART_WEIGHTS:
                raise ValueError(f"unknown loss weight {key!r}; expected keys among {sorted(CHART_WEIGHTS)}")
            merged[key] = float(value)
        if num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples}")
        self.weights = merged
        self.num_samples = int(num_samples)

    def forward(self, out: Mapping[str, Sequence[Tensor]], points: Tensor, normals: Tensor) -> dict[str, Tensor]:
        """Loss terms of the final charts.

        Args:
            out: the network output: ``verts`` (per iteration (B, V, 3)), ``faces`` (per iteration (F, 3)), ``edges``
                (per iteration (E, 2)) and optionally ``touch_chart_loss`` (0-dim).
            points: (B, M, 3) float GT points in the prediction's frame; normals: (B, M, 3) (not used: the authors'
                loss has no normal term; the argument keeps the reconstruction criterion's signature).

        Returns:
            dict of 0-dim float tensors: ``chamfer``, ``edge``, ``touch_chart`` (unweighted) and ``loss``.
        """
        verts, faces, edges = out["verts"][-1], out["faces"][-1], out["edges"][-1]
        terms = {"chamfer": sampled_chamfer(verts, faces, points, self.num_samples).mean()}
        zero = verts.new_zeros(())
        terms["edge"] = edge_length_loss(verts, edges) if self.weights["edge"] else zero
        touch = out.get("touch_chart_loss")
        terms["touch_chart"] = touch if isinstance(touch, Tensor) else zero
        terms["loss"] = sum(self.weights[k] * terms[k] for k in CHART_WEIGHTS)  # type: ignore[assignment]
        return terms
