"""Opt-in fused per-particle kernels of :class:`tvrecon.sim.mpm.solver.MLSMPM`, built with ``torch.compile``.

The eager step runs ~60 small kernels per step. The per-particle arithmetic between the grid transfers is written
here once more as plain elementwise torch (3x3 matrices as nine ``(P,)`` rows, no ``matmul``, no data-dependent
control flow) so that inductor fuses each function into a few loops (C++/OpenMP on CPU, Triton on GPU). Every
per-particle tensor is channel-first, ``(3, P)`` / ``(9, P)`` contiguous: inductor's C++ backend vectorizes a loop
only when its loads and stores are contiguous along the particles (``(P, 3, 3)`` rows give scalar loops).

- :func:`stencil_base`: ``base``, ``fx`` and each scene's bounds of ``base`` (:func:`stencil_weights` adds the 27
  quadratic B-spline weights; the kernels below compute them from ``fx`` where they use them,
  :func:`tvrecon.sim.mpm.block_grid.bspline_weights`);
- :func:`block_index`: each particle's base node on the block grid (``grid.block_layout``'s ``lin``);
- :func:`polar_fixed`: the scaled Newton polar decomposition of :func:`tvrecon.sim.mpm.materials.polar_decomposition`,
  a fixed number of iterations with a per-particle stop (a particle keeps the iterate at which its step fell below
  the tolerance, as in the eager loop); it also returns whether every particle converged, else the caller falls
  back to the eager iteration;
- :func:`p2g_contrib`: fixed-corotated Kirchhoff stress (paper eq. 4), the affine momentum matrix of eq. 6 and each
  particle's 4 x 27 stencil contribution ``w [m, m v + A (x_i - x_p)]`` as one ``(n, 108)`` row per particle of
  one chunk, sliced inside the compiled code (the ``index_add_`` scatter stays eager);
- :func:`node_sums`: the 27 stencil offsets of the scattered rows summed onto their nodes (P2G's grid; compiled as
  part of :func:`tvrecon.sim.mpm.compiled.grid.grid_collide`, the grid update and colliders);
- :func:`g2p_update`: the gather of the 27 node velocities straight from the grid, as 9 runs of 3 neighbouring nodes
  (no bounds asserts: the indices are inside the block by construction), the APIC sums and the particle update of
  eq. 8-11;
- :func:`share_force`: the collider's node forces shared out over the particles (``grid.share_node_force``, the
  reading's force field) with the same gather of 9 runs.

Only the no-grad step uses them (the press and data generation); a step that needs autograd runs the eager code.
The results equal the eager step to float32 round-off (fused arithmetic and a per-particle instead of a
per-batch Newton stop); ``tests/sim/mpm/test_mpm_compile.py`` checks it.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tvrecon.sim.mpm.block_grid import bspline_weights
from tvrecon.sim.mpm.materials import POLAR_FIXED_ITERS

__all__ = [
    "NEWTON_ITERS",
    "stencil_base",
    "stencil_weights",
    "block_index",
    "polar_fixed",
    "p2g_contrib",
    "node_sums",
    "g2p_update",
    "share_force",
]

#: fixed Newton iterations of :func:`polar_fixed` (eager needs 1 at F = R, ~3 for |sigma - 1| ~ 0.1); a step where a
#: particle has not converged after them recomputes R with the eager loop.
NEWTON_ITERS = POLAR_FIXED_ITERS

_OFFS = [(i, j, k) for i in range(3) for j in range(3) for k in range(3)]  # stencil offsets, i slowest


def _cof(X: list[Tensor]) -> list[Tensor]:
    """Cofactor matrix (det(X) X^-T) of nine rows, row-major (rows r1 x r2, r2 x r0, r0 x r1)."""
    x00, x01, x02, x10, x11, x12, x20, x21, x22 = X
    return [
        x11 * x22 - x12 * x21,
        x12 * x20 - x10 * x22,
        x10 * x21 - x11 * x20,
        x21 * x02 - x22 * x01,
        x22 * x00 - x20 * x02,
        x20 * x01 - x21 * x00,
        x01 * x12 - x02 * x11,
        x02 * x10 - x00 * x12,
        x00 * x11 - x01 * x10,
    ]


def _mm(A: list[Tensor], B: list[Tensor], bt: bool = False) -> list[Tensor]:
    """A @ B (or A @ B^T) of row-major nine-row matrices."""
    if bt:
        return [
            A[3 * a] * B[3 * b] + A[3 * a + 1] * B[3 * b + 1] + A[3 * a + 2] * B[3 * b + 2]
            for a in range(3)
            for b in range(3)
        ]
    return [A[3 * a] * B[b] + A[3 * a + 1] * B[3 + b] + A[3 * a + 2] * B[6 + b] for a in range(3) for b in range(3)]


def stencil_weights(xt: Tensor, inv_dx: float, B: int = 1) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """From positions xt (3, P) of B scenes of P / B contiguous particles each: ``base_f = floor(x/dx - 0.5)``
    (3, P), ``fx = x/dx - base_f`` (3, P), w (27, P) and the per-scene bounds of base_f, lo_f and hi_f (3, B) (for
    :func:`tvrecon.sim.mpm.block_grid.block_dims`; exact, as min and max are)."""
    base_f, fx, lo_f, hi_f = stencil_base(xt, inv_dx, B)
    return base_f, fx, torch.stack(bspline_weights(fx), 0), lo_f, hi_f


def stencil_base(xt: Tensor, inv_dx: float, B: int = 1) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`stencil_weights` without the weights (the compiled step's kernel ``"stencil"``: the (27, P) table is
    ~110 bytes a particle written once and read by P2G and G2P; they compute the weights from ``fx`` instead):
    base_f, fx (3, P) and the per-scene bounds lo_f, hi_f (3, B)."""
    Xg = xt * inv_dx
    base_f = torch.floor(Xg - 0.5)
    fx = Xg - base_f
    per_scene = base_f.view(3, B, -1)
    return base_f, fx, per_scene.amin(2), per_scene.amax(2)


def block_index(base_f: Tensor, lo: Tensor, dims: Tensor) -> Tensor:
    """Linear block-grid index (P,) int64 of each particle's base node, as
    :func:`tvrecon.sim.mpm.block_grid.block_layout` numbers them (scene-major, then i, j, k; integer arithmetic, so the
    same values).

    base_f: (3, P) base nodes (float, whole numbers) of B scenes of P / B contiguous particles; lo: (3, B) int64 block
    origins; dims: (3,) int64 ``[D1, D2, D0 D1 D2]`` (a tensor, so that a new block size does not recompile)."""
    B = lo.shape[1]
    local = base_f.to(torch.int64).view(3, B, -1) - lo[:, :, None]
    scene = torch.arange(B, device=base_f.device, dtype=torch.int64)[:, None]
    return ((local[0] * dims[0] + local[1]) * dims[1] + local[2] + scene * dims[2]).view(-1)


def polar_fixed(Ft: Tensor, stop: float, n_iter: int = NEWTON_ITERS) -> tuple[Tensor, Tensor]:
    """R of F = R S by ``n_iter`` scaled Newton steps, each particle frozen once its step is below ``stop``.

    Ft: (9, P) entries of F, row-major. Returns R as (9, P) and a 0-dim bool: every particle converged (False also
    when a step was not finite).
    """
    X = list(Ft.unbind(0))
    done = torch.zeros_like(X[0], dtype=torch.bool)
    for _ in range(n_iter):
        cof = _cof(X)
        det = X[0] * cof[0] + X[1] * cof[1] + X[2] * cof[2]
        inv_t = [c / det for c in cof]
        n_inv = sum(c * c for c in inv_t)
        n_x = sum(e * e for e in X)
        gs = torch.sqrt(torch.sqrt(n_inv / n_x))  # ^(1/4); pow is a slow libm call in the kernel
        X_new = [0.5 * (gs * e + c / gs) for e, c in zip(X, inv_t)]
        delta = (X_new[0] - X[0]).abs()
        for e, en in zip(X[1:], X_new[1:]):
            delta = torch.maximum(delta, (en - e).abs())
        X = [torch.where(done, e, en) for e, en in zip(X, X_new)]
        done = done | (delta < stop)
    return torch.stack(X, 0), done.all()  # a NaN step never counts as converged


def p2g_contrib(
    Ft: Tensor,
    Rt: Tensor,
    Ct: Tensor,
    vt: Tensor,
    fx: Tensor,
    m: Tensor,
    vol: Tensor,
    s0: int,
    n: int,
    mu: float,
    lam: float,
    dt: float,
    dx: float,
    inv_dx: float,
) -> Tensor:
    """Per particle ``w_o [m, m v + A (o - fx) dx]`` for the 27 offsets o: the (n, 108) scatter rows of eq. 5-6 of
    particles ``s0 .. s0 + n`` (particle-major, so that ``index_add_`` along the nodes adds one contiguous row per
    particle).

    Channel-first whole-step inputs: Ft, Rt, Ct (9, P), vt, fx (3, P), m, vol (P,); the weights come from fx
    (:func:`~tvrecon.sim.mpm.block_grid.bspline_weights`). The chunk is sliced
    here, inside the compiled code, so that each chunk's call passes the same tensors (with slices as arguments, the
    guards and wrappers of a call cost ~40 us more per chunk in a microbenchmark).
    ``A = m C - (4 dt V0 / dx^2) tau`` with the fixed-corotated Kirchhoff stress
    ``tau = 2 mu (F - R) F^T + lam (J - 1) J I`` (rows c = mass, momentum x, y, z; then offset o, as the eager P2G).
    """
    sl = slice(s0, s0 + n)
    Ft, Rt, Ct, vt, fx = Ft[:, sl], Rt[:, sl], Ct[:, sl], vt[:, sl], fx[:, sl]
    w = torch.stack(bspline_weights(fx), 0)  # (27, n)
    m, vol = m[sl], vol[sl]
    Fr, Rr, Cr = Ft.unbind(0), Rt.unbind(0), Ct.unbind(0)
    cof = _cof(Fr)
    J = Fr[0] * cof[0] + Fr[1] * cof[1] + Fr[2] * cof[2]
    tau = _mm([2.0 * mu * (f - r) for f, r in zip(Fr, Rr)], Fr, bt=True)
    p = lam * (J - 1.0) * J
    tau = [t + p if e in (0, 4, 8) else t for e, t in enumerate(tau)]
    gamma = (4.0 * dt * inv_dx * inv_dx) * vol
    A = [m * c - gamma * t for c, t in zip(Cr, tau)]
    f0, f1, f2 = fx.unbind(0)
    # momentum at offset o: m v + dx A (o - fx) = mv0 + dx (A o)
    mv0 = torch.stack([m * vt[a] - dx * (A[3 * a] * f0 + A[3 * a + 1] * f1 + A[3 * a + 2] * f2) for a in range(3)], 0)
    dA = torch.stack([dx * e for e in A], 0).view(3, 3, -1)  # (a, axis, P)
    r = torch.arange(3, device=w.device, dtype=w.dtype)
    oi, oj, ok = (o[None, :, None] for o in (r.repeat_interleave(9), r.repeat_interleave(3).repeat(3), r.repeat(9)))
    mom = w[None] * (mv0[:, None] + oi * dA[:, 0, None] + oj * dA[:, 1, None] + ok * dA[:, 2, None])  # (3, 27, P)
    # as broadcast tensors, not 108 stacked rows: inductor then writes the transposed rows in vectorized tiles
    # (2x faster than a 108-way stack, same values)
    return torch.cat([(w * m)[None], mom], 0).reshape(108, -1).T.contiguous()


def node_sums(G: Tensor, S0: int, S1: int) -> Tensor:
    """The 27 stencil offsets of the scattered rows summed onto their nodes: (N, 108) -> (4, N) [m_i, (m v)_i].

    Row n of G holds, for the particles whose base node is n, the sums of ``w [m, m v + A (x_i - x_p)]`` per channel
    c and offset o = (i, j, k) (column ``27 c + o``); node n gets ``sum_o G[n - (i S0 + j S1 + k), 27 c + o]`` (zero
    where that row is before the block grid).
    """
    N = G.shape[0]
    pad = 2 * S0 + 2 * S1 + 2
    Gp = torch.nn.functional.pad(G, (0, 0, pad, 0))
    out = []
    for c in range(4):
        acc = None
        for o, (i, j, k) in enumerate(_OFFS):
            s = pad - (i * S0 + j * S1 + k)
            t = Gp[s : s + N, 27 * c + o]
            acc = t if acc is None else acc + t
        out.append(acc)
    return torch.stack(out, 0)


def g2p_update(
    gv: Tensor,
    offs: Tensor,
    lin: Tensor,
    fx: Tensor,
    xt: Tensor,
    Ft: Tensor,
    alpha: Tensor | None,
    hvt: Tensor | None,
    dt: float,
    inv_dx: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Gather v(base + o) straight from the grid velocities, then paper eq. 8-11.

    gv: (N - 2, 9) runs of 3 neighbouring node velocities, row n = ``[v(n), v(n + 1), v(n + 2)]`` (the caller's
    ``(N, 3)`` grid viewed with strides (3, 1), no copy: a particle's 27 nodes are 9 such runs); offs: (9,) int64
    node-axis offset of each run (``i S0 + j S1``); lin: (P,) base node of each particle. One index per run instead of
    one per node. Channel-first: fx, xt (3, P) (the weights come from fx,
    :func:`~tvrecon.sim.mpm.block_grid.bspline_weights`), Ft (9, P), hvt (3, P) or (3, 1) hand velocity. Returns x, v
    (3, P), C, F (9, P).
    """
    w = bspline_weights(fx)
    g = gv[lin[None, :] + offs[:, None]]  # (9, P, 9): indirect loads fused into the sums below by inductor
    S = []  # S[c] = [sum_o w v_c, sum_o w v_c o_i, ... o_j, ... o_k]
    for c in range(3):
        t = [w[o] * g[o // 3, :, 3 * (o % 3) + c] for o in range(27)]  # o = (i, j, k): run 3 i + j, node k
        row = [sum(t)]
        for ax in range(3):
            row.append(
                sum(t[o] for o, off in enumerate(_OFFS) if off[ax] == 1)
                + 2.0 * sum(t[o] for o, off in enumerate(_OFFS) if off[ax] == 2)
            )
        S.append(row)
    v_pic = [S[c][0] for c in range(3)]
    Cn = [(4.0 * inv_dx) * (S[a][1 + b] - v_pic[a] * fx[b]) for a in range(3) for b in range(3)]
    if alpha is None:
        v_new = v_pic
    elif hvt is None:
        v_new = [alpha * vp for vp in v_pic]
    else:
        v_new = [alpha * v_pic[a] + (1.0 - alpha) * hvt[a] for a in range(3)]
    x_new = torch.stack([xt[a] + dt * v_new[a] for a in range(3)], 0)
    Fr = Ft.unbind(0)
    CF = _mm(Cn, Fr)
    F_new = torch.stack([f + dt * cf for f, cf in zip(Fr, CF)], 0)
    return x_new, torch.stack(v_new, 0), torch.stack(Cn, 0), F_new


def share_force(pm: Tensor, offs: Tensor, lin: Tensor, fx: Tensor, mass: Tensor) -> Tensor:
    """``f_p = m_p sum_o w_o (f / m)(base + o)`` (:func:`tvrecon.sim.mpm.block_grid.share_node_force`, another summation
    order): pm (N - 2, 9) runs of the per-mass node forces ``f_i / m_i`` (as ``gv`` of :func:`g2p_update`), offs (9,),
    lin (P,), fx (3, P) (the weights, :func:`~tvrecon.sim.mpm.block_grid.bspline_weights`), mass (P,). Returns the
    (P, 3) particle forces."""
    w = bspline_weights(fx)
    g = pm[lin[None, :] + offs[:, None]]  # (9, P, 9)
    acc = [sum(w[o] * g[o // 3, :, 3 * (o % 3) + c] for o in range(27)) for c in range(3)]
    return torch.stack([mass * a for a in acc], 1)
