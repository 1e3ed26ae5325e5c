"""Chamfer distance (squared distances, mean each way, summed) with nearest-neighbour indices.

Memory: nearest neighbours are searched without autograd in chunks (never a (B, N, M, 3) tensor), then the squared
distances to the chosen neighbours are recomputed with autograd; the gradient equals that of the min.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from tvrecon.utils.shape_check import check_shape

__all__ = ["ChamferDistance", "ChamferResult", "chamfer_distance", "chamfer_terms", "nearest_neighbors"]

_REDUCTIONS = ("mean", "sum", "none")


class ChamferResult(NamedTuple):
    """Everything a chamfer evaluation finds.

    loss: (B,) per-sample chamfer (or reduced), dist_xy: (B, N) squared distance from each x to its nearest y,
    idx_xy: (B, N) int64 index into y, dist_yx: (B, M), idx_yx: (B, M) int64 index into x. Padded entries are 0.
    """

    loss: Tensor
    dist_xy: Tensor
    idx_xy: Tensor
    dist_yx: Tensor
    idx_yx: Tensor


def _lengths_mask(lengths: Tensor | None, B: int, N: int, device: torch.device, name: str) -> Tensor:
    if lengths is None:
        return torch.ones(B, N, dtype=torch.bool, device=device)
    if lengths.shape != (B,):
        raise ValueError(f"{name} must have shape (B,) = ({B},), got {tuple(lengths.shape)}")
    if (lengths < 1).any() or (lengths > N).any():
        raise ValueError(f"{name} must lie in [1, {N}], got {lengths.tolist()}")
    return torch.arange(N, device=device)[None] < lengths.to(device)[:, None]


def nearest_neighbors(x: Tensor, y: Tensor, y_mask: Tensor | None = None, chunk: int = 2048) -> tuple[Tensor, Tensor]:
    """For each point of x, its nearest point in y (squared Euclidean distance).

    Args:
        x: (B, N, 3) float.
        y: (B, M, 3) float.
        y_mask: (B, M) bool, False = padding (never chosen).
        chunk: rows of x handled at once (None: keep each (B, chunk, M) distance block under ~2^25 entries).

    Returns:
        dist (B, N) float squared distance (differentiable in x and y) and idx (B, N) int64 into y.
    """
    check_shape(x, "(B, N, 3)", "x")
    check_shape(y, "(B, N, 3)", "y")
    if x.shape[0] != y.shape[0]:
        raise ValueError(f"x and y must have the same batch size, got {x.shape[0]} and {y.shape[0]}")
    if chunk is None:
        chunk = max(1, (1 << 25) // max(1, x.shape[0] * y.shape[1]))
    # float32 at least and outside autocast: a bfloat16 search would confuse points closer than ~1% of their range
    with torch.no_grad(), torch.autocast(x.device.type, enabled=False):
        # argmin_j |x_i - y_j|^2 = argmin_j (|y_j|^2 - 2 x_i . y_j): one batched matmul per chunk and no sqrt/square
        # passes over the (B, n, M) block (torch.cdist expands the same way for large clouds). Both clouds are first
        # centred on y's mean, which keeps the expansion's cancellation small for clouds far from the origin. |y_j|^2
        # rides in the product as a fourth coordinate ([x_i, 1] . [-2 y_j, |y_j|^2]): adding it as baddbmm's
        # broadcast input would first copy it over the whole (B, n, M) block.
        dtype = torch.promote_types(torch.promote_types(x.dtype, y.dtype), torch.float32)
        centre = y.detach().to(dtype).mean(dim=1, keepdim=True)  # (B, 1, 3)
        xc, yc = x.detach().to(dtype) - centre, y.detach().to(dtype) - centre
        y_sq = yc.square().sum(-1, keepdim=True)  # (B, M, 1)
        if y_mask is not None:
            y_sq = y_sq.masked_fill(~y_mask[..., None], float("inf"))
        xa = torch.cat([xc, torch.ones_like(xc[..., :1])], dim=-1)  # (B, N, 4)
        yt = torch.cat([-2.0 * yc, y_sq], dim=-1).transpose(1, 2).contiguous()  # (B, 4, M)
        idx = [
            torch.bmm(xa[:, start : start + chunk], yt).argmin(dim=2) for start in range(0, x.shape[1], chunk)
        ]  # each (B, n)
        idx_t = torch.cat(idx, dim=1) if idx else torch.zeros(x.shape[:2], dtype=torch.long, device=x.device)
    nearest = torch.gather(y, 1, idx_t[..., None].expand(-1, -1, 3))  # (B, N, 3)
    return (x - nearest).square().sum(-1), idx_t


def chamfer_terms(
    x: Tensor,
    y: Tensor,
    x_lengths: Tensor | None = None,
    y_lengths: Tensor | None = None,
    reduction: str = "mean",
) -> ChamferResult:
    """Chamfer distance with its nearest-neighbour terms.

    Per sample: ``mean_{p in x} min_{q in y} |p - q|^2 + mean_{q in y} min_{p in x} |p - q|^2``.

    Args:
        x: (B, N, 3) float; y: (B, M, 3) float.
        x_lengths: (B,) int64 valid points of each x (None = all); y_lengths: (B,) likewise.
        reduction: ``"mean"`` over the batch, ``"sum"`` over the batch, or ``"none"`` (B,).

    Returns:
        ``ChamferResult`` (see its docstring).
    """
    if reduction not in _REDUCTIONS:
        raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")
    check_shape(x, "(B, N, 3)", "x")
    check_shape(y, "(B, N, 3)", "y")
    B, N, M = x.shape[0], x.shape[1], y.shape[1]
    if y.shape[0] != B:
        raise ValueError(f"x and y must have the same batch size, got {B} and {y.shape[0]}")
    xm = _lengths_mask(x_lengths, B, N, x.device, "x_lengths")
    ym = _lengths_mask(y_lengths, B, M, y.device, "y_lengths")
    dist_xy, idx_xy = nearest_neighbors(x, y, ym if y_lengths is not None else None)
    dist_yx, idx_yx = nearest_neighbors(y, x, xm if x_lengths is not None else None)
    dist_xy = dist_xy * xm
    dist_yx = dist_yx * ym
    loss = dist_xy.sum(1) / xm.sum(1) + dist_yx.sum(1) / ym.sum(1)  # (B,)
    if reduction == "mean":
        loss = loss.mean()
    elif reduction == "sum":
        loss = loss.sum()
    return ChamferResult(loss, dist_xy, idx_xy, dist_yx, idx_yx)


def chamfer_distance(
    x: Tensor,
    y: Tensor,
    x_lengths: Tensor | None = None,
    y_lengths: Tensor | None = None,
    reduction: str = "mean",
) -> Tensor:
    """Chamfer distance: squared distances, mean each way, summed.

    Args:
        x: (B, N, 3) float; y: (B, M, 3) float.
        x_lengths, y_lengths: (B,) int64 valid points (None = all).
        reduction: ``"mean"`` | ``"sum"`` | ``"none"``.

    Returns:
        scalar float (mean/sum) or (B,) float (none). Use ``chamfer_terms`` for the nearest indices.
    """
    return chamfer_terms(x, y, x_lengths, y_lengths, reduction).loss


class ChamferDistance(nn.Module):
    """Module wrapper of ``chamfer_distance``."""

    def __init__(self, reduction: str = "mean") -> None:
        super().__init__()
        if reduction not in _REDUCTIONS:
            raise ValueError(f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")
        self.reduction = reduction

    def forward(self, x: Tensor, y: Tensor, x_lengths: Tensor | None = None, y_lengths: Tensor | None = None) -> Tensor:
        """See ``chamfer_distance``."""
        return chamfer_distance(x, y, x_lengths, y_lengths, self.reduction)
