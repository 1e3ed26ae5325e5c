"""Pixel2Mesh mesh losses and the weighted total over deformation stages.

Terms (per sample, then reduced over the batch):

* ``normal_loss``: for every predicted edge (a, b), ``|cos(v_a - v_b, n_a)|`` where ``n_a`` is the ground-truth normal
  of the GT point nearest to vertex a; mean over edges (an edge should lie in the tangent plane).
* ``edge_length_loss``: mean squared edge length.
* ``laplacian_loss``: mean squared norm of the uniform Laplacian coordinates ``delta_v = v - mean_{N(v)} v'``, or, with
  ``before`` given, of their change ``delta_v(after) - delta_v(before)`` across a deformation block (Pixel2Mesh).
* ``move_loss``: mean squared vertex displacement ``|v_after - v_before|^2`` across a deformation block.

``mesh_loss_terms`` (and its module ``MeshLoss``) applies them at every stage with Pixel2Mesh's relative weights as
defaults, checked against the TensorFlow-aligned config of the public PyTorch port of Pixel2Mesh: chamfer 1.0,
normal 1.6e-4, edge 0.1, laplacian 0.5, move 0.033 (the original TensorFlow code scales chamfer by 3000, normal 0.5,
edge 300, laplacian 1500, move 100: the same ratios); Laplacian stage factors (0.2, 1, 1); the move term from the
second stage on. Chamfer is the symmetric sum of the two means (the project's
definition, weight 1 on both directions).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.losses.chamfer import chamfer_terms
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "DEFAULT_WEIGHTS",
    "MeshLoss",
    "edge_length_loss",
    "laplacian_coordinates",
    "laplacian_loss",
    "mesh_loss_terms",
    "move_loss",
    "normal_loss",
]

DEFAULT_WEIGHTS: dict[str, float] = {"chamfer": 1.0, "normal": 1.6e-4, "edge": 0.1, "laplacian": 0.5, "move": 0.033}
_ALIASES = {"laplace": "laplacian"}
_REDUCTIONS = ("mean", "sum", "none")


def _reduce(x: Tensor, reduction: str) -> Tensor:
    if reduction == "mean":
        return x.mean()
    if reduction == "sum":
        return x.sum()
    if reduction == "none":
        return x
    raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")


def edge_length_loss(verts: Tensor, edges: Tensor, reduction: str = "mean") -> Tensor:
    """Mean squared edge length.

    Args:
        verts: (B, V, 3) float; edges: (E, 2) int64.
        reduction: ``"mean"`` | ``"sum"`` over the batch, or ``"none"`` (B,).
    """
    check_shape(verts, "(B, V, 3)", "verts")
    check_shape(edges, "(E, 2)", "edges")
    d = verts[:, edges[:, 0]] - verts[:, edges[:, 1]]  # (B, E, 3)
    return _reduce(d.square().sum(-1).mean(1), reduction)


def laplacian_coordinates(verts: Tensor, edges: Tensor) -> Tensor:
    """Uniform Laplacian coordinates ``v - mean of neighbours``.

    Args:
        verts: (B, V, 3) float; edges: (E, 2) int64 undirected.

    Returns:
        (B, V, 3) float (isolated vertices give 0).
    """
    check_shape(verts, "(B, V, 3)", "verts")
    check_shape(edges, "(E, 2)", "edges")
    V = verts.shape[1]
    src = torch.cat([edges[:, 0], edges[:, 1]])
    dst = torch.cat([edges[:, 1], edges[:, 0]])
    nsum = torch.zeros_like(verts).index_add(1, dst, verts[:, src])
    deg = torch.zeros(V, dtype=verts.dtype, device=verts.device).index_add(
        0, dst, torch.ones_like(dst, dtype=verts.dtype)
    )
    mean = nsum / deg.clamp(min=1)[None, :, None]
    return torch.where(deg[None, :, None] > 0, verts - mean, torch.zeros_like(verts))


def laplacian_loss(verts: Tensor, edges: Tensor, before: Tensor | None = None, reduction: str = "mean") -> Tensor:
    """Laplacian smoothing (``before`` None) or Pixel2Mesh's Laplacian change across a deformation block.

    Args:
        verts: (B, V, 3) float vertices after deformation; edges: (E, 2) int64.
        before: (B, V, 3) float vertices before the block, or None.
        reduction: ``"mean"`` | ``"sum"`` | ``"none"``.

    Returns:
        mean over vertices of ``|delta(verts) - delta(before)|^2`` (or ``|delta(verts)|^2``), reduced.
    """
    lap = laplacian_coordinates(verts, edges)
    if before is not None:
        if before.shape != verts.shape:
            raise ValueError(f"before must have the shape of verts {tuple(verts.shape)}, got {tuple(before.shape)}")
        lap = lap - laplacian_coordinates(before, edges)
    return _reduce(lap.square().sum(-1).mean(1), reduction)


def move_loss(verts: Tensor, before: Tensor, reduction: str = "mean") -> Tensor:
    """Mean squared vertex displacement across a deformation block.

    Args:
        verts: (B, V, 3) float after; before: (B, V, 3) float before.
    """
    check_shape(verts, "(B, V, 3)", "verts")
    if before.shape != verts.shape:
        raise ValueError(f"before must have the shape of verts {tuple(verts.shape)}, got {tuple(before.shape)}")
    return _reduce((verts - before).square().sum(-1).mean(1), reduction)


def normal_loss(
    verts: Tensor, edges: Tensor, gt_normals: Tensor, nearest_idx: Tensor, reduction: str = "mean"
) -> Tensor:
    """Pixel2Mesh normal consistency: predicted edges should be orthogonal to the GT normal at their first vertex.

    Args:
        verts: (B, V, 3) float predicted vertices; edges: (E, 2) int64.
        gt_normals: (B, M, 3) float unit normals of the GT points.
        nearest_idx: (B, V) int64 index of the GT point nearest to each predicted vertex (``chamfer_terms().idx_xy``).
        reduction: ``"mean"`` | ``"sum"`` | ``"none"``.

    Returns:
        mean over edges of ``|cos(edge, normal)|``, reduced.
    """
    check_shape(verts, "(B, V, 3)", "verts")
    check_shape(edges, "(E, 2)", "edges")
    check_shape(gt_normals, "(B, M, 3)", "gt_normals")
    if gt_normals.shape[0] != verts.shape[0]:
        raise ValueError(f"gt_normals must have shape (B, M, 3) with B={verts.shape[0]}, got {tuple(gt_normals.shape)}")
    if nearest_idx.shape != verts.shape[:2]:
        raise ValueError(
            f"nearest_idx must have shape (B, V) = {tuple(verts.shape[:2])}, got {tuple(nearest_idx.shape)}"
        )
    e = F.normalize(verts[:, edges[:, 0]] - verts[:, edges[:, 1]], dim=-1)  # (B, E, 3)
    nn_idx = nearest_idx[:, edges[:, 0]]  # (B, E)
    n = F.normalize(torch.gather(gt_normals, 1, nn_idx[..., None].expand(-1, -1, 3)), dim=-1)  # (B, E, 3)
    return _reduce((e * n).sum(-1).abs().mean(1), reduction)


def _merge_weights(weights: Mapping[str, float] | None) -> dict[str, float]:
    merged = dict(DEFAULT_WEIGHTS)
    for k, v in (weights or {}).items():
        key = _ALIASES.get(str(k), str(k))
        if key not in DEFAULT_WEIGHTS:
            raise ValueError(f"unknown loss weight {k!r}; expected keys among {sorted(DEFAULT_WEIGHTS)}")
        merged[key] = float(v)
    return merged


def mesh_loss_terms(
    out: Mapping[str, Sequence[Tensor]],
    points: Tensor,
    normals: Tensor,
    weights: Mapping[str, float] | None = None,
    stage_weights: Sequence[float] | None = None,
    laplacian_stage_weights: Sequence[float] = (0.2, 1.0, 1.0),
    move_from_stage: int = 1,
    points_lengths: Tensor | None = None,
) -> dict[str, Tensor]:
    """Pixel2Mesh loss over every deformation stage.

    ``loss = sum_s stage_w[s] * (w_chamfer CD_s + w_normal N_s + w_edge E_s + w_laplacian lap_w[s] L_s
    + w_move M_s [s >= move_from_stage])``. Terms whose weight is 0 are not computed (reported as 0).

    Args:
        out: the reconstructor's output: per-stage lists ``verts`` (B, V_s, 3), ``verts_before`` (B, V_s, 3),
            ``edges`` (E_s, 2).
        points: (B, M, 3) float GT points in the prediction's (camera) frame.
        normals: (B, M, 3) float GT unit normals in the same frame.
        weights: overrides of ``DEFAULT_WEIGHTS`` (keys ``chamfer, normal, edge, laplacian, move``; ``laplace`` is
            accepted for ``laplacian``).
        stage_weights: factor of each stage's loss (None = 1 for every stage).
        laplacian_stage_weights: extra Laplacian factor per stage (Pixel2Mesh 0.2, 1, 1; missing stages use 1).
        move_from_stage: first stage with a move term (Pixel2Mesh: 1, the first block may move freely).
        points_lengths: (B,) int64 valid GT points (None = all).

    Returns:
        dict of 0-dim float tensors: ``chamfer``, ``normal``, ``edge``, ``laplacian``, ``move`` (unweighted, summed over
        stages with ``stage_weights``), ``chamfer_final`` (last stage's chamfer) and ``loss`` (the weighted total).
    """
    verts, before, edges = out["verts"], out["verts_before"], out["edges"]
    if not (len(verts) == len(before) == len(edges)) or len(verts) == 0:
        raise ValueError("out must hold equally long, non-empty lists 'verts', 'verts_before' and 'edges'")
    check_shape(points, "(B, M, 3)", "points")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {tuple(points.shape)}, got {tuple(normals.shape)}")
    if stage_weights is not None and len(stage_weights) != len(verts):
        raise ValueError(f"stage_weights needs one weight per stage ({len(verts)}), got {list(stage_weights)}")
    w = _merge_weights(weights)
    zero = verts[0].new_zeros(())
    names = ("chamfer", "normal", "edge", "laplacian", "move")
    terms = dict.fromkeys(names, zero)
    total = zero
    chamfer_final = zero
    for s, (v, vb, e) in enumerate(zip(verts, before, edges)):
        sw = 1.0 if stage_weights is None else float(stage_weights[s])
        lap_w = float(laplacian_stage_weights[s]) if s < len(laplacian_stage_weights) else 1.0
        stage = dict.fromkeys(names, zero)
        if w["chamfer"] != 0 or w["normal"] != 0 or s == len(verts) - 1:
            ch = chamfer_terms(v, points, y_lengths=points_lengths)
            stage["chamfer"] = ch.loss
            if s == len(verts) - 1:
                chamfer_final = ch.loss
            if w["normal"] != 0:
                stage["normal"] = normal_loss(v, e, normals, ch.idx_xy)
        if w["edge"] != 0:
            stage["edge"] = edge_length_loss(v, e)
        if w["laplacian"] != 0 and lap_w != 0:
            stage["laplacian"] = laplacian_loss(v, e, before=vb)
        if w["move"] != 0 and s >= move_from_stage:
            stage["move"] = move_loss(v, vb)
        weighted = (
            sum(w[k] * stage[k] for k in ("chamfer", "normal", "edge", "move"))
            + w["laplacian"] * lap_w * stage["laplacian"]
        )
        total = total + sw * weighted
        terms = {k: terms[k] + sw * stage[k] for k in names}
    terms["chamfer_final"] = chamfer_final
    terms["loss"] = total
    return terms


class MeshLoss(nn.Module):
    """Module wrapper of ``mesh_loss_terms`` (weights fixed at construction).

    Args:
        weights: overrides of ``DEFAULT_WEIGHTS``.
        stage_weights: factor of each stage's loss (None = 1).
        laplacian_stage_weights: extra Laplacian factor per stage (Pixel2Mesh: 0.2, 1, 1).
        move_from_stage: first stage that gets the move term (Pixel2Mesh: 1).
    """

    def __init__(
        self,
        weights: Mapping[str, float] | None = None,
        stage_weights: Sequence[float] | None = None,
        laplacian_stage_weights: Sequence[float] = (0.2, 1.0, 1.0),
        move_from_stage: int = 1,
    ) -> None:
        super().__init__()
        self.weights = _merge_weights(weights)
        self.stage_weights = None if stage_weights is None else [float(x) for x in stage_weights]
        self.laplacian_stage_weights = [float(x) for x in laplacian_stage_weights]
        self.move_from_stage = move_from_stage

    def forward(
        self,
        out: Mapping[str, Sequence[Tensor]],
        points: Tensor,
        normals: Tensor,
        points_lengths: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """See ``mesh_loss_terms``."""
        return mesh_loss_terms(
            out,
            points,
            normals,
            self.weights,
            self.stage_weights,
            self.laplacian_stage_weights,
            self.move_from_stage,
            points_lengths,
        )
