"""Reference versions of the two hot spots of a reconstruction training step, for ``bench_train_step.py``.

* ``index_add_forward``: ``GraphConv`` with the neighbour sum ``agg_{v' in N(v)} W1 x_v'`` as a gather of both ends
  of every edge and an ``index_add`` (what ``tvrecon.models.components.gcn.GraphConv`` did before its sparse neighbour
  matrix).
* ``cdist_nearest_neighbors``: the chamfer's nearest-neighbour search with ``torch.cdist(...).square()`` (what
  ``tvrecon.losses.chamfer.nearest_neighbors`` did before the expanded-square search).

Same parameters, same results to float32 round-off.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tvrecon.models.components.gcn import GraphConv


def index_add_forward(conv: GraphConv, x: Tensor, edges: Tensor, neighbours: Tensor | None = None) -> Tensor:
    """``GraphConv.forward`` by gather + ``index_add`` (``neighbours`` is ignored).

    Args: x (B, V, C_in) float; edges (E, 2) int64 undirected. Returns (B, V, C_out) float.
    """
    h = conv.neighbour_linear(x)  # (B, V, C_out)
    src = torch.cat([edges[:, 0], edges[:, 1]])
    dst = torch.cat([edges[:, 1], edges[:, 0]])
    agg = torch.zeros_like(h).index_add(1, dst, h[:, src])  # (B, V, C_out) sum over neighbours
    if conv.aggregate == "mean":
        deg = torch.zeros(x.shape[1], dtype=h.dtype, device=h.device).index_add(0, dst, torch.ones_like(h[0, src, 0]))
        agg = agg / deg.clamp(min=1)[None, :, None]
    return conv.self_linear(x) + agg


def cdist_nearest_neighbors(
    x: Tensor, y: Tensor, y_mask: Tensor | None = None, chunk: int = 2048
) -> tuple[Tensor, Tensor]:
    """``nearest_neighbors`` by ``torch.cdist``: x (B, N, 3), y (B, M, 3) float, y_mask (B, M) bool or None.

    Returns dist (B, N) float squared distance to the nearest y (differentiable) and idx (B, N) int64.
    """
    with torch.no_grad():
        idx = []
        for start in range(0, x.shape[1], chunk):
            d = torch.cdist(x[:, start : start + chunk].detach(), y.detach()).square()  # (B, n, M)
            if y_mask is not None:
                d = d.masked_fill(~y_mask[:, None, :], float("inf"))
            idx.append(d.argmin(dim=2))
        idx_t = torch.cat(idx, dim=1)
    nearest = torch.gather(y, 1, idx_t[..., None].expand(-1, -1, 3))  # (B, N, 3)
    return (x - nearest).square().sum(-1), idx_t
