"""The sparse block grid of :class:`tvrecon.sim.mpm.solver.MLSMPM`: where the nodes are, and which ones a particle
touches.

Each scene gets a block of nodes aligned to the global lattice and covering only the bounding box of its particles'
stencils (:func:`block_layout`); nodes are numbered scene-major, then ``i``, ``j``, ``k``, so a stencil offset is a
fixed shift along the node axis (:func:`shift_nodes`). :class:`Stencil` is what P2G and G2P share in one step;
:class:`Transfer` is what the solver keeps of the last step to share the collider force out over the particles
(:func:`share_node_force`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = [
    "FIX_HINT",
    "MAX_GRID_NODES",
    "Stencil",
    "Transfer",
    "block_dims",
    "block_index",
    "block_layout",
    "bounds_row",
    "check_grid_speed",
    "dims_from_bounds",
    "node_major_scatter",
    "scene_bounds",
    "share_node_force",
    "shift_nodes",
    "shift_rows",
    "stencil_offsets",
    "stencil_shifts",
]

FIX_HINT = "reduce dt / hand speed, increase n_grid"
MAX_GRID_NODES = 64_000_000


class Stencil(NamedTuple):
    """Particle -> node stencil of one step, shared by P2G and G2P (P particles, B scenes, N block-grid nodes)."""

    fx: Tensor  # (P, 3) particle position in cells relative to its base node, in [0.5, 1.5)
    w: Tensor | None  # (27, P) quadratic B-spline weight of each stencil node, offsets (i, j, k) with i slowest;
    # None where the step computes them from fx where it uses them (the compiled step): see weights()
    lo: Tensor  # (B, 3) int64 global node index of each scene's block origin
    lin: Tensor  # (P,) int64 linear block-grid index of each particle's base node
    D: list[int]  # block dims per scene (nodes per axis)
    n_nodes: int  # N = B * D[0] * D[1] * D[2]
    chunk: int  # particles per chunk of the stencil passes (>= P: all at once)

    def weights(self, particles: Tensor | None = None) -> Tensor:
        """(27, P) weights, or (27, K) of the K ``particles``: the step's table, or computed from fx."""
        if self.w is not None:
            return self.w if particles is None else self.w[:, particles]
        fx = self.fx if particles is None else self.fx[particles]
        return torch.stack(bspline_weights(fx.T), 0)


class Transfer(NamedTuple):
    """The last step's transfer, references to tensors the step computed anyway (detached)."""

    lin: Tensor  # (P,) base node of each particle
    w: Tensor | None  # (27, P) stencil weights (None: computed from fx when asked, see weights())
    node_mass: Tensor  # (N,) grid mass
    node_force: Tensor  # (N, 3) force the collider(s) exerted on each node
    strides: tuple[int, int]  # (S0, S1): node-axis strides of i and j
    fx: Tensor | None = None  # (3, P) channel-first fx of the stencil, where w is None

    def weights(self) -> Tensor:
        """The (27, P) stencil weights: ``w``, or computed from ``fx``."""
        if self.w is not None:
            return self.w
        if self.fx is None:
            raise ValueError("a Transfer needs its weights w or its stencil's fx")
        return torch.stack(bspline_weights(self.fx), 0)


def bspline_weights(fxt: Tensor) -> list[Tensor]:
    """The 27 quadratic B-spline weights (offsets (i, j, k), i slowest) of particles ``fxt`` (3, P) cells from their
    base nodes, as 27 (P,) rows: ``w_ijk = wa_0[i] wa_1[j] wa_2[k]``, ``wa = [0.5 (1.5 - f)^2, 0.75 - (f - 1)^2,
    0.5 (f - 0.5)^2]`` (paper eq. 5-8's weights). The compiled kernels compute them in this order where they use
    them instead of reading a (27, P) table (~110 bytes a particle; the fused C++ transfers the same way)."""
    wa = [(0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2) for f in fxt.unbind(0)]
    return [wa[0][i] * wa[1][j] * wa[2][k] for i in range(3) for j in range(3) for k in range(3)]


def stencil_offsets(device: torch.device, dtype: torch.dtype) -> Tensor:
    """(27, 3) node offsets (i, j, k) in {0,1,2}^3, i slowest."""
    r = torch.arange(3, device=device)
    o = torch.stack(torch.meshgrid(r, r, r, indexing="ij"), -1).reshape(27, 3)
    return o.to(dtype)


@functools.lru_cache(maxsize=64)
def stencil_shifts(S0: int, S1: int, device: torch.device) -> Tensor:
    """(27,) int64 node-axis offset of each stencil node (i, j, k), i slowest, from its particle's base node in a block
    of node strides ``S0`` (i) and ``S1`` (j); kept per block shape, as a press steps the same block for a while."""
    o = stencil_offsets(device, torch.int64)
    return o[:, 0] * S0 + o[:, 1] * S1 + o[:, 2]


def shift_nodes(t: Tensor, s: int) -> Tensor:
    """Shift along the last (node) axis: out[..., n] = t[..., n - s], zero filled (s < 0 shifts the other way)."""
    if s == 0:
        return t
    return torch.nn.functional.pad(t, (s, -s))


def shift_rows(t: Tensor, s: int) -> Tensor:
    """Shift along the first (node) axis: out[n, ...] = t[n - s, ...], zero filled (:func:`shift_nodes`, node-major)."""
    if s == 0:
        return t
    return torch.nn.functional.pad(t, (0, 0) * (t.dim() - 1) + (s, -s))


def node_major_scatter(MT: Tensor, w: Tensor, o_aug_t: Tensor, lin: Tensor, n_nodes: int, S0: int, S1: int) -> Tensor:
    """P2G's scatter (paper eq. 5, eq:mass, and eq. 6, eq:momentum) with a particle's 108 stencil values as one row.

    The solver's default layout scatters (108, P) columns into a (108, N) node grid: 108 values of one particle lie
    ``N`` floats apart, an uncoalesced atomic add each on a GPU (``indexFuncLargeIndex``, 24% of a batch-64 paper
    step's GPU time on an H100). Here the grid is (N, 108): each particle adds one contiguous row, and the 27 stencil
    offsets are summed by shifting whole node rows (k, then j, then i), the same sums as the default layout.

    Args:
        MT: (4, 4, P) per-particle matrix M[c, j] of the [1, o] weights j (mass row c = 0, momentum rows c = 1..3).
        w: (27, P) quadratic B-spline weights per stencil offset o = (i, j, k). o_aug_t: (27, 4) rows [1, o].
        lin: (P,) int64 block node index of each particle's base node. n_nodes: N. S0, S1: node strides of i and j.

    Returns:
        (4, N) grid of [m_i, (m v)_i] (a transposed view).
    """
    P = w.shape[1]
    # one (4P, 4) @ (4, 27) GEMM: a (P, 4, 4) @ (4, 27) product would be a batched GEMM of P tiny matrices, which
    # cuBLAS splits into a launch per 65,535 of them (:mod:`tvrecon.sim.mpm.small_matmul`)
    rows = MT.permute(2, 0, 1).reshape(4 * P, 4)  # (4P, 4): row (p, c)
    contrib = (rows @ o_aug_t.T).view(P, 4, 27) * w.T[:, None, :]  # (P, 4, 27): (m, m v) per stencil node
    G = torch.zeros(n_nodes, 108, dtype=MT.dtype, device=MT.device).index_add(0, lin, contrib.reshape(P, 108))
    G = G.view(n_nodes, 4, 3, 3, 3)  # (node, c, i, j, k)
    T = G[..., 0] + shift_rows(G[..., 1], 1) + shift_rows(G[..., 2], 2)  # (N, 4, 3, 3)
    U = T[..., 0] + shift_rows(T[..., 1], S1) + shift_rows(T[..., 2], 2 * S1)  # (N, 4, 3)
    return (U[..., 0] + shift_rows(U[..., 1], S0) + shift_rows(U[..., 2], 2 * S0)).T  # (4, N): mass, momentum


def scene_bounds(base_f: Tensor, batch: Tensor | None, B: int, block: int | None = None) -> tuple[Tensor, Tensor]:
    """Per-scene lowest and highest base node, lo_f and hi_f (B, 3) float, of the base nodes ``base_f`` (P, 3).

    ``block``: particles per scene when ``batch`` is the contiguous layout ``arange(B).repeat_interleave(block)``
    (as :class:`tvrecon.sim.press.loop.PressLoop` builds it): plain reductions over a ``(B, block, 3)`` view instead
    of a scatter (same values: min and max are exact). None: any ``batch``."""
    if batch is None:
        return base_f.amin(0, keepdim=True), base_f.amax(0, keepdim=True)
    if block is not None:
        lo_f, hi_f = torch.aminmax(base_f.reshape(B, block, 3), dim=1)
        return lo_f, hi_f
    idx = batch[:, None].expand(-1, 3)
    lo_f = base_f.new_zeros(B, 3).scatter_reduce_(0, idx, base_f, "amin", include_self=False)
    hi_f = base_f.new_zeros(B, 3).scatter_reduce_(0, idx, base_f, "amax", include_self=False)
    return lo_f, hi_f


def bounds_row(lo_f: Tensor, hi_f: Tensor) -> Tensor:
    """(9,) the block's nodes per axis (the largest scene's), the lowest and the highest base node over all scenes:
    what the host needs to size the block grid (:func:`dims_from_bounds`)."""
    ext = hi_f - lo_f + 3.0  # nodes per axis: base .. base + 2
    return torch.cat([ext.amax(0), lo_f.amin(0), hi_f.amax(0)])


def dims_from_bounds(bounds: list[float], B: int) -> list[int]:
    """Block dims [3] from :func:`bounds_row`'s nine values, read on the host. Raises FloatingPointError on a
    non-finite or exploded state."""
    if not all(math.isfinite(b) for b in bounds):
        raise FloatingPointError(f"MPM state became NaN/inf (particle positions not finite): {FIX_HINT}")
    D = [int(d) for d in bounds[:3]]
    if B * D[0] * D[1] * D[2] > MAX_GRID_NODES:
        raise FloatingPointError(f"MPM state exploded: particles spread over {D} grid cells per scene; {FIX_HINT}")
    return D


def block_dims(lo_f: Tensor, hi_f: Tensor, B: int) -> list[int]:
    """Block dims [3] (nodes per axis, the same for every scene) from the per-scene bounds of the base nodes, lo_f and
    hi_f (B, 3) (float, whole numbers): one host read. Raises FloatingPointError on a non-finite or exploded state."""
    return dims_from_bounds(bounds_row(lo_f, hi_f).tolist(), B)


def block_index(
    base_f: Tensor, lo_f: Tensor, batch: Tensor | None, B: int, block: int | None, D: list[int], clamp: bool = False
) -> tuple[Tensor, Tensor]:
    """The per-scene origin lo (B, 3) int64 and the linear block-grid node index (P,) of each particle's base node,
    for block dims ``D`` (:func:`block_layout`'s last part).

    ``clamp``: ``D`` was not read from these bounds (a window of unread steps, ``MLSMPM.trust_next``): a base node
    outside the block is moved to its edge, so that the step stays in range (its result is then wrong, and the caller,
    who reads the bounds afterwards, runs it again)."""
    nb = D[0] * D[1] * D[2]
    lo = lo_f.to(torch.int64)  # (B, 3)
    base = base_f.to(torch.int64)
    if batch is not None and block is not None:
        local = (base.view(B, block, 3) - lo[:, None]).view(-1, 3)
    else:
        local = base - (lo if batch is None else lo[batch])  # (P, 3)
    if clamp:
        local = torch.clamp(local, min=_zeros3(local.device), max=_top_nodes(tuple(D), local.device))
    lin = (local * _strides(D[1], D[2], local.device)).sum(1)  # (i D1 + j) D2 + k
    if batch is not None:
        if block is not None:
            lin = (lin.view(B, block) + _scene_starts(B, nb, lin.device)).view(-1)
        else:
            lin = lin + batch * nb
    return lo, lin


@functools.lru_cache(maxsize=64)
def _strides(D1: int, D2: int, device: torch.device) -> Tensor:
    """(3,) int64 node strides of i, j and k in a block of dims (., D1, D2)."""
    return torch.tensor([D1 * D2, D2, 1], dtype=torch.int64, device=device)


@functools.lru_cache(maxsize=64)
def _scene_starts(B: int, nb: int, device: torch.device) -> Tensor:
    """(B, 1) int64 first node of each of B scene blocks of ``nb`` nodes."""
    return torch.arange(B, device=device)[:, None] * nb


@functools.lru_cache(maxsize=8)
def _zeros3(device: torch.device) -> Tensor:
    return torch.zeros(3, dtype=torch.int64, device=device)


@functools.lru_cache(maxsize=64)
def _top_nodes(D: tuple[int, ...], device: torch.device) -> Tensor:
    """(3,) int64: the highest base node of a block of dims ``D`` (its stencil's last node is the block's)."""
    return torch.tensor(D, dtype=torch.int64, device=device) - 3


def block_layout(
    base_f: Tensor, batch: Tensor | None, B: int, block: int | None = None
) -> tuple[Tensor, Tensor, list[int]]:
    """Local grid blocks of the particles' base nodes ``base_f`` (P, 3) (float, whole numbers).

    ``block``: particles per scene of the contiguous layout (:func:`scene_bounds`), or None.

    Returns the per-scene origin lo (B, 3) int64, the linear node index of each particle's base node (P,) and the
    block dims D [3]. Raises FloatingPointError on a non-finite or exploded state.
    """
    lo_f, hi_f = scene_bounds(base_f, batch, B, block)
    D = block_dims(lo_f, hi_f, B)
    lo, lin = block_index(base_f, lo_f, batch, B, block, D)
    return lo, lin, D


def check_grid_speed(vmax: float, dt: float, dx: float) -> None:
    """Raise FloatingPointError when the fastest grid node (``vmax``, its largest velocity component) would move more
    than one cell in a step, or is NaN."""
    if not vmax * dt <= dx:  # also catches NaN
        raise FloatingPointError(
            f"MPM state exploded (grid speed {vmax:.3g} moves {vmax * dt / dx:.3g} cells per step, NaN or > 1): "
            f"{FIX_HINT}"
        )


def share_node_force(transfer: Transfer, mass: Tensor, o_int: Tensor) -> Tensor:
    """Node forces shared out over the particles: ``f_p = m_p sum_i w_ip f_i / m_i``.

    Args:
        transfer: the step's :class:`Transfer`.
        mass: (P,) particle masses of that step's state.
        o_int: (27, 3) int64 stencil offsets (:func:`stencil_offsets`).
    Returns:
        (P, 3) force on each particle, detached.
    """
    lin, gm, node_force, (S0, S1) = transfer.lin, transfer.node_mass, transfer.node_force, transfer.strides
    w = transfer.weights()
    if mass.shape != lin.shape:
        raise ValueError(f"mass must be (P,) = {tuple(lin.shape)} like the last step's particles, got {mass.shape}")
    idx = lin[None, :] + (o_int[:, 0] * S0 + o_int[:, 1] * S1 + o_int[:, 2])[:, None]  # (27, P) stencil nodes
    per_mass = node_force / torch.where(gm > 0, gm, torch.ones_like(gm))[:, None]  # (N, 3)
    acc = (w[:, :, None] * per_mass[idx]).sum(0)  # (P, 3)
    return mass.detach().to(acc)[:, None] * acc
