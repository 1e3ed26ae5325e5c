"""Pixel2Mesh graph deformer (paper eq. 13-15, which have no LaTeX labels).

* ``GraphConv``: ``f_v' = W0 x_v + sum_{v' in N(v)} W1 x_v' + b`` (the form of eq. 14-15), by default
  degree-normalised (mean over neighbours, see ``GraphConv``). The neighbour sum is one product with a sparse CSR
  matrix, block-diagonal over the batch (``neighbour_matrix``, built once per mesh level by ``MeshDeformer``),
  instead of gathering both ends of every edge and ``index_add`` (``benchmarks/reference_train.py``; speed in
  ``benchmarks/speed/bench_train_step.py``); its transpose is prebuilt for the backward (``neighbour_operator``), and
  ``W0`` and ``W1`` run as one matrix product.
* ``GResBlock``: two graph convs with ReLU and a residual connection, ``(x + conv2(relu(conv1(x)))) / 2`` as in
  Pixel2Mesh.
* ``PerceptualPooling`` (in ``tvrecon.models.components.perceptual``): vertices (camera frame) are projected with K
  (kornia) and each visual stage is sampled bilinearly with ``grid_sample(align_corners=False)`` (pixel centres at
  integers: see ``projection.pixel_to_grid``), then the samples are concatenated. **Choice:** the paper average-pools
  the stages to a common size before concatenating them into one "perceptual feature"; sampling each stage at its own
  resolution and concatenating is the Pixel2Mesh original and keeps the fine stages sharp (same channels, same
  spirit). The deformer hands the samples to the first graph conv unevaluated (``PerceptualSample``): sampling is
  linear, so the conv multiplies a feature map by its weights before sampling wherever that is the cheaper order (the
  8x8 and 4x4 maps of a 128 px view against 2,466 vertices at the last stage), and samples the smallest maps as a
  product with their bilinear weights.
* ``DeformationBlock``: ``g_v = concat(f_v, x_v, proj(f_p))`` (eq. 13) -> graph conv -> G-ResNet blocks -> a hidden
  feature ``f_v`` for the next block and a coordinate update. **Choice:** the last graph conv predicts an offset added
  to ``x_v`` (initialised small, so an untrained deformer stays close to the ellipsoid) instead of absolute
  coordinates.
* ``MeshDeformer``: three deformation blocks with edge-midpoint unpooling between them (156 -> 618 -> 2466).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.models.components.ellipsoid import EllipsoidTemplate, unpool_features
from tvrecon.models.components.perceptual import PerceptualPooling, PerceptualSample
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "DeformationBlock",
    "GResBlock",
    "GraphConv",
    "MeshDeformer",
    "NeighbourOperator",
    "neighbour_matrix",
    "neighbour_operator",
]

_AGGREGATES = ("mean", "sum")


def neighbour_matrix(edges: Tensor, num_vertices: int, aggregate: str = "mean", batch_size: int = 1) -> Tensor:
    """The neighbour operator of a mesh graph as a sparse matrix, block-diagonal over a batch of meshes.

    Args:
        edges: (E, 2) int64 undirected edges (each listed once; a repeated edge counts twice, as in a loop).
        num_vertices: V.
        aggregate: ``"sum"`` (entry 1 per neighbour) or ``"mean"`` (entry 1 / degree).
        batch_size: B, the number of copies of the mesh (one diagonal block each).

    Returns:
        (B*V, B*V) float32 sparse CSR matrix ``A`` on ``edges.device``: for features h (B, V, C),
        ``(A @ h.reshape(B*V, C)).reshape(B, V, C)[b, v]`` is the sum or mean of ``h[b]`` over the neighbours of v
        (zero for an isolated vertex).
    """
    if aggregate not in _AGGREGATES:
        raise ValueError(f"aggregate must be 'mean' or 'sum', got {aggregate!r}")
    check_shape(edges, "(E, 2)", "edges")
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if edges.numel() and (int(edges.min()) < 0 or int(edges.max()) >= num_vertices):
        raise ValueError(
            f"edges must index vertices in [0, {num_vertices}), got [{int(edges.min())}, {int(edges.max())}]"
        )
    src = torch.cat([edges[:, 0], edges[:, 1]]).long()  # (2E,)
    dst = torch.cat([edges[:, 1], edges[:, 0]]).long()
    values = torch.ones(src.shape[0], dtype=torch.float32, device=edges.device)
    if aggregate == "mean":
        deg = torch.zeros(num_vertices, dtype=torch.float32, device=edges.device).index_add(0, dst, values)
        values = values / deg[dst]
    offset = (torch.arange(batch_size, device=edges.device) * num_vertices)[:, None]  # (B, 1)
    rows, cols = (dst[None] + offset).flatten(), (src[None] + offset).flatten()  # (B*2E,)
    n = batch_size * num_vertices
    coo = torch.sparse_coo_tensor(
        torch.stack([rows, cols]), values.repeat(batch_size), (n, n), check_invariants=False
    ).coalesce()  # repeated entries are summed
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return coo.to_sparse_csr()


class NeighbourOperator(NamedTuple):
    """A mesh level's neighbour operator and its transpose, both sparse CSR (B*V, B*V) (``neighbour_operator``).

    The transpose is the backward's operator: keeping it built saves converting ``matrix.t()`` on every backward.
    ``bfloat16`` holds the two as bfloat16 COO matrices once a bfloat16 product on the CPU asked for them.
    """

    matrix: Tensor
    transpose: Tensor
    bfloat16: dict[str, tuple[Tensor, Tensor]]

    def cpu_bfloat16(self) -> tuple[Tensor, Tensor]:
        """(matrix, transpose) as coalesced bfloat16 COO, built on first use."""
        if "coo" not in self.bfloat16:
            self.bfloat16["coo"] = tuple(  # type: ignore[assignment]
                m.to_sparse_coo().to(torch.bfloat16).coalesce() for m in (self.matrix, self.transpose)
            )
        return self.bfloat16["coo"]


def neighbour_operator(
    edges: Tensor, num_vertices: int, aggregate: str = "mean", batch_size: int = 1
) -> NeighbourOperator:
    """``neighbour_matrix`` and its transpose (both CSR), built once per mesh level by ``MeshDeformer``.

    Args: as :func:`neighbour_matrix`. Returns a :class:`NeighbourOperator`.
    """
    matrix = neighbour_matrix(edges, num_vertices, aggregate, batch_size)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return NeighbourOperator(matrix, matrix.t().to_sparse_csr(), {})


class _SparseProduct(torch.autograd.Function):
    """``A @ h`` for a constant sparse ``A`` with the prebuilt ``A^T`` as the backward's operator."""

    @staticmethod
    def forward(ctx: Any, matrix: Tensor, transpose: Tensor, h: Tensor) -> Tensor:  # noqa: D102
        ctx.transpose = transpose
        return matrix @ h

    @staticmethod
    def backward(ctx: Any, grad: Tensor) -> tuple[None, None, Tensor]:  # noqa: D102
        return None, None, ctx.transpose @ grad.contiguous()


def _aggregate(operator: Tensor | NeighbourOperator, h: Tensor) -> Tensor:
    """Neighbour sums: operator (B*V, B*V) sparse from ``neighbour_matrix`` or ``neighbour_operator``, h (B, V, C)
    float -> (B, V, C) float.

    Computed in at least float32 (float64 stays float64) outside autocast: sparse products under mixed precision are
    not supported on every device. One exception: bfloat16 features on the CPU with a ``NeighbourOperator`` take its
    bfloat16 COO matrices (MKL's CSR product has no bfloat16 kernel; the COO one does, and a graph conv then skips
    casting its features to float32 and back). The result has h's dtype.
    """
    B, V, C = h.shape
    if isinstance(operator, NeighbourOperator) and h.dtype == torch.bfloat16 and h.device.type == "cpu":
        with torch.autocast(device_type="cpu", enabled=False):
            matrix, transpose = operator.cpu_bfloat16()
            return _SparseProduct.apply(matrix, transpose, h.reshape(B * V, C)).reshape(B, V, C)
    dtype = torch.promote_types(h.dtype, torch.float32)
    with torch.autocast(device_type=h.device.type, enabled=False):
        flat = h.to(dtype).reshape(B * V, C)
        if isinstance(operator, NeighbourOperator):
            matrix, transpose = (m if m.dtype == dtype else m.to(dtype) for m in (operator.matrix, operator.transpose))
            out = _SparseProduct.apply(matrix, transpose, flat)
        else:
            out = (operator if operator.dtype == dtype else operator.to(dtype)) @ flat
    return out.reshape(B, V, C).to(h.dtype)


def _operator_shape(neighbours: Tensor | NeighbourOperator) -> tuple[int, ...]:
    matrix = neighbours.matrix if isinstance(neighbours, NeighbourOperator) else neighbours
    return tuple(matrix.shape)


GraphInput = Tensor | Sequence[Tensor | PerceptualSample]


class GraphConv(nn.Module):
    """Graph convolution ``W0 x_v + sum_{v' in N(v)} W1 x_v' + b`` (``aggregate="sum"``, paper eq. 14-15 as written) or
    ``W0 x_v + mean_{v' in N(v)} W1 x_v' + b`` (``aggregate="mean"``, degree-normalised as in Pixel2Mesh's code).

    On the near-regular ellipsoid meshes (degree 4 to 6, mostly 6) the two differ only by a rescaling of W1; the mean
    keeps activations from growing with depth, so it is the default.

    Both products run as one: ``[W0; W1] x`` (one matrix product of 2 C_out columns), then the W1 half goes through
    the sparse neighbour operator. The input may also be given as its parts (dense (B, V, C_k) tensors and a
    :class:`PerceptualSample`, in the order of the input channels): the concatenation is then never built.

    Args:
        in_features: input channels C_in.
        out_features: output channels C_out.
        aggregate: ``"mean"`` or ``"sum"`` over neighbours.
    """

    def __init__(self, in_features: int, out_features: int, aggregate: str = "mean") -> None:
        super().__init__()
        if aggregate not in _AGGREGATES:
            raise ValueError(f"aggregate must be 'mean' or 'sum', got {aggregate!r}")
        self.aggregate = aggregate
        self.self_linear = nn.Linear(in_features, out_features)  # W0 (+ bias)
        self.neighbour_linear = nn.Linear(in_features, out_features, bias=False)  # W1

    def forward(self, x: GraphInput, edges: Tensor, neighbours: Tensor | NeighbourOperator | None = None) -> Tensor:
        """Args: x (B, V, C_in) float, or its parts along the channels (see the class); edges (E, 2) int64
        undirected; neighbours: optional (B*V, B*V) sparse ``neighbour_matrix(edges, V, self.aggregate, B)`` or
        ``neighbour_operator(...)``, built by the caller once for many convs (None = build it).

        Returns (B, V, C_out) float.
        """
        parts = [x] if isinstance(x, Tensor) else list(x)
        first = next((p for p in parts if isinstance(p, Tensor)), None)
        ref = first if first is not None else parts[0].grid[..., 0, 0]  # type: ignore[union-attr]
        for part in parts:
            if isinstance(part, Tensor):
                check_shape(part, "(B, V, C)", "x")
        check_shape(edges, "(E, 2)", "edges")
        B, V = ref.shape[:2]
        if neighbours is None:
            neighbours = neighbour_matrix(edges, V, self.aggregate, B)
        elif _operator_shape(neighbours) != (B * V, B * V):
            raise ValueError(
                f"neighbours must have shape (B*V, B*V) = ({B * V}, {B * V}), got {_operator_shape(neighbours)}"
            )
        C = self.self_linear.out_features
        weight = torch.cat([self.self_linear.weight, self.neighbour_linear.weight])  # (2C, C_in): [W0; W1]
        bias = torch.cat([self.self_linear.bias, self.self_linear.bias.new_zeros(C)])  # (2C,): b on the W0 half
        y_self, y_neighbour = self._project(parts, weight, bias).split(C, dim=-1)  # (B, V, C) each
        return y_self + _aggregate(neighbours, y_neighbour)

    def _project(self, parts: list[Tensor | PerceptualSample], weight: Tensor, bias: Tensor) -> Tensor:
        """``concat(parts) @ weight.T + bias`` for weight (C, C_in), bias (C,): adjacent dense parts are joined, a
        :class:`PerceptualSample` is projected (``PerceptualSample.project``). Returns (B, V, C) float."""
        groups: list[Tensor | PerceptualSample] = []
        run: list[Tensor] = []
        for part in parts:
            if isinstance(part, Tensor):
                run.append(part)
                continue
            if run:
                groups.append(run[0] if len(run) == 1 else torch.cat(run, dim=-1))
                run = []
            groups.append(part)
        if run:
            groups.append(run[0] if len(run) == 1 else torch.cat(run, dim=-1))
        width = sum(g.shape[-1] if isinstance(g, Tensor) else g.channels for g in groups)
        if width != weight.shape[1]:
            raise ValueError(f"x must have {weight.shape[1]} channels in all its parts, got {width}")
        out: Tensor | None = None
        col = 0
        pending: Tensor | None = bias  # added by the first dense product (in its addmm), else at the end
        for g in groups:
            c = g.shape[-1] if isinstance(g, Tensor) else g.channels
            w = weight[:, col : col + c]
            col += c
            if isinstance(g, Tensor):
                term, pending = F.linear(g, w, pending), None
            else:
                term = g.project(w)
            out = term if out is None else out + term
        assert out is not None
        return out if pending is None else out + pending.to(out.dtype)


class GResBlock(nn.Module):
    """Residual pair of graph convolutions: ``(x + conv2(relu(conv1(x)))) * 0.5``, followed by ReLU."""

    def __init__(self, features: int, aggregate: str = "mean") -> None:
        super().__init__()
        self.conv1 = GraphConv(features, features, aggregate)
        self.conv2 = GraphConv(features, features, aggregate)

    def forward(self, x: Tensor, edges: Tensor, neighbours: Tensor | NeighbourOperator | None = None) -> Tensor:
        """Args: x (B, V, C) float; edges (E, 2) int64; neighbours (B*V, B*V) sparse or None (see ``GraphConv``).

        Returns (B, V, C) float.
        """
        if neighbours is None:
            neighbours = neighbour_matrix(edges, x.shape[1], self.conv1.aggregate, x.shape[0])
        h = F.relu(self.conv1(x, edges, neighbours), inplace=True)  # in place: fewer passes over (B, V, C)
        h = self.conv2(h, edges, neighbours)
        return F.relu((x + h).mul_(0.5), inplace=True)


class DeformationBlock(nn.Module):
    """One Pixel2Mesh deformation block (paper eq. 13-15).

    Args:
        in_features: channels of ``g_v`` = hidden of the previous block (0 for the first) + 3 + perceptual channels.
        hidden: width of the graph convolutions.
        num_blocks: G-ResNet blocks.
        aggregate: neighbour aggregation of the graph convs (``"mean"`` or ``"sum"``).
    """

    def __init__(self, in_features: int, hidden: int = 192, num_blocks: int = 6, aggregate: str = "mean") -> None:
        super().__init__()
        self.conv_in = GraphConv(in_features, hidden, aggregate)
        self.blocks = nn.ModuleList([GResBlock(hidden, aggregate) for _ in range(num_blocks)])
        self.conv_out = GraphConv(hidden, 3, aggregate)
        with torch.no_grad():  # small initial offsets: an untrained deformer stays close to the ellipsoid
            self.conv_out.self_linear.weight.mul_(0.01)
            self.conv_out.self_linear.bias.zero_()
            self.conv_out.neighbour_linear.weight.mul_(0.01)

    def forward(
        self, g: GraphInput, verts: Tensor, edges: Tensor, neighbours: Tensor | NeighbourOperator | None = None
    ) -> tuple[Tensor, Tensor]:
        """Args: g (B, V, C_in) float, or its parts (see ``GraphConv``); verts (B, V, 3) float; edges (E, 2) int64;
        neighbours (B*V, B*V) sparse, a ``NeighbourOperator`` or None (see ``GraphConv``).

        Returns: new vertices (B, V, 3) float and hidden features (B, V, hidden) float.
        """
        if neighbours is None:
            neighbours = neighbour_matrix(edges, verts.shape[1], self.conv_in.aggregate, verts.shape[0])
        h = F.relu(self.conv_in(g, edges, neighbours))  # paper eq. 14 (f_v^{l+1}), then the G-ResNet blocks
        for block in self.blocks:
            h = block(h, edges, neighbours)
        return verts + self.conv_out(h, edges, neighbours), h  # paper eq. 15 (x_v^{l+1}), as an offset


class MeshDeformer(nn.Module):
    """Ellipsoid -> three deformation blocks with edge-midpoint unpooling between them.

    Args:
        feature_channels: channels of the visual stages pooled by every vertex.
        hidden: graph conv width.
        num_blocks: G-ResNet blocks per deformation block.
        num_stages: deformation blocks (mesh levels), 3 in Pixel2Mesh.
        radii, distance, rings, segments: the initial ellipsoid (see ``ellipsoid.uv_ellipsoid``).
        aggregate: neighbour aggregation of the graph convs (``"mean"`` default, or ``"sum"``; see ``GraphConv``).
    """

    def __init__(
        self,
        feature_channels: Sequence[int] = (64, 128, 256, 512),
        hidden: int = 192,
        num_blocks: int = 6,
        num_stages: int = 3,
        radii: Sequence[float] = (0.35, 0.35, 0.25),
        distance: float = 2.0,
        rings: int = 11,
        segments: int = 14,
        aggregate: str = "mean",
    ) -> None:
        super().__init__()
        self.template = EllipsoidTemplate(num_stages, radii, distance, rings, segments)
        self.pool = PerceptualPooling()
        self.num_stages = num_stages
        self.aggregate = aggregate
        # neighbour operators of the template's levels, built on first use per (level, batch size, device): the edges
        # never change, so a training step reuses them instead of rebuilding (and re-validating) three per forward
        self._neighbours: dict[tuple[int, int, torch.device], NeighbourOperator] = {}
        perceptual = int(sum(feature_channels))
        self.stages = nn.ModuleList(
            [
                DeformationBlock((hidden if s > 0 else 0) + 3 + perceptual, hidden, num_blocks, aggregate)
                for s in range(num_stages)
            ]
        )

    def _level_neighbours(self, level: int, batch_size: int) -> NeighbourOperator:
        """The cached ``neighbour_operator`` of template level ``level`` for ``batch_size`` meshes (B*V, B*V)."""
        edges = self.template.edges(level)
        key = (level, batch_size, edges.device)
        if key not in self._neighbours:
            V = self.template.verts(level).shape[0]
            self._neighbours[key] = neighbour_operator(edges, V, self.aggregate, batch_size)
        return self._neighbours[key]

    def _deform(
        self,
        s: int,
        block: nn.Module,
        g: list[Tensor | PerceptualSample],
        x: Tensor,
        edges: Tensor,
        neighbours: NeighbourOperator,
    ) -> tuple[Tensor, Tensor]:
        """Run deformation block ``s`` on ``g_v`` (B, V_s, C), given as its parts ([f_v,] x_v, the perceptual sample),
        at vertices x (B, V_s, 3): new vertices and hidden features. Subclasses that give the blocks more per-vertex
        input override this (the loop stays here)."""
        return block(g, x, edges, neighbours)

    def forward(self, features: Sequence[Tensor], K: Tensor, image_size: tuple[int, int]) -> dict[str, list[Tensor]]:
        """Deform the ellipsoid under the perceptual features.

        Args:
            features: float visual maps (B, C_j, h_j, w_j).
            K: (B, 3, 3) float intrinsics.
            image_size: (H, W) of the view.

        Returns:
            dict of per-stage lists: ``verts`` (B, V_s, 3) predicted camera-frame vertices, ``verts_before``
            (B, V_s, 3) the block's input vertices (ellipsoid or unpooled previous prediction), ``faces`` (F_s, 3),
            ``edges`` (E_s, 2), ``init_verts`` (V_s, 3) the template at that level.
        """
        B = K.shape[0]
        x = self.template.verts(0).to(K.dtype)[None].expand(B, -1, -1)  # (B, V0, 3)
        hidden: Tensor | None = None
        out: dict[str, list[Tensor]] = {"verts": [], "verts_before": [], "faces": [], "edges": [], "init_verts": []}
        for s, block in enumerate(self.stages):
            if s > 0:
                parent = self.template.parent_edges(s)
                x = unpool_features(x, parent)
                hidden = unpool_features(hidden, parent)
            edges = self.template.edges(s)
            pooled = self.pool.sample(x, K, features, image_size)  # (B, V_s, sum C), sampled by the block's conv_in
            # paper eq. 13 (no label): g_v = concat(f_v, x_v, proj(f_p)), handed over as its parts
            g = [x, pooled] if hidden is None else [hidden, x, pooled]
            neighbours = self._level_neighbours(s, B)  # one operator for all the level's convs
            new_x, hidden = self._deform(s, block, g, x, edges, neighbours)
            out["verts_before"].append(x)
            out["verts"].append(new_x)
            out["faces"].append(self.template.faces(s))
            out["edges"].append(edges)
            out["init_verts"].append(self.template.verts(s))
            x = new_x
        return out
