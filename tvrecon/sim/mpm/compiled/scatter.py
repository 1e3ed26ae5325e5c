"""A fused P2G scatter for the compiled MLS-MPM step on CPU (opt-in ``compile=True``): one small C++ loop that
computes each particle's stress and affine momentum and adds its 27 stencil contributions straight onto the
``(N, 4)`` node grid ``[m_i, (m v)_i]`` (paper eq. 5-6).

The inductor path it replaces on CPU (``compiled.kernels.p2g_contrib`` rows of 108 per particle, an eager ``index_add_``
of those rows, then ``node_sums``) writes and reads ~10 MB per step for a paper pad and pays ~20 ns per scattered row
in ``index_add_``; here each particle's 27 x 4 values go to the 9 runs of 3 neighbouring nodes (12 contiguous
floats each) without a buffer, with the B-spline weights computed from ``fx`` (a (27, P) table read from 27 rows
of P was ~60% of this loop's time). The sums are the same terms added in another order (per node, particle by
particle) and fused into FMAs, so the grid equals the row path to float32 round-off. The particles go in tiles of
256: each one's stress and affine momentum 8 particles at a time, then its stencil onto the grid (a paper step's
scatter 1.6x faster than one particle at a time, ``benchmarks/bench_cpp_loops.py``).

Built once per process with inductor's own C++ toolchain and cache (``torch._inductor.codecache.CppCodeCache``, the
compiler the compiled path needs anyway). Used only for float32 CPU tensors on one torch thread (the loop is serial:
scattered adds of different particles may hit the same node); anything else, or a failed build, keeps the row path.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop

__all__ = ["SOURCE", "fused_p2g", "p2g_grid_available"]

#: the C++ source, in tiles of 256 particles: phase 1, 8 particles at a time (8-float vectors over the channel-first
#: arrays; the tile's last < 8 one by one, the same code on floats), computes per particle the 13 numbers
#: q = [m, then per axis a: mv0_a, dx A_a0, dx A_a1, dx A_a2] into a (13, 256) tile; phase 2 adds
#: ``w_o [m, mv0 + dx A o]`` (w_o from fx, :func:`tvrecon.sim.mpm.block_grid.bspline_weights`) for the 27 offsets
#: o = (i, j, k) to node ``lin + i S0 + j S1 + k`` of the (N, 4) grid, per run (i, j) the nodes k = 0, 1 as one
#: 8-float vector and k = 2 as a 4-float one (GCC / Clang vector extension: another compiler fails the build, and the
#: row path stays). The arithmetic is ``compiled.kernels.p2g_contrib``'s, term by term in its order, with products
#: fused into FMAs (``fp-contract=fast`` for this source only: inductor builds with it off).
SOURCE = r"""
#pragma GCC optimize("fp-contract=fast")
#include <cstdint>
#include <cstring>
typedef float v4 __attribute__((vector_size(16)));
typedef float v8 __attribute__((vector_size(32)));
constexpr int64_t TILE = 256;
template <typename V> static inline V ld(const float* p) { V r; std::memcpy(&r, p, sizeof(V)); return r; }
template <typename V> static inline void st(float* p, V v) { std::memcpy(p, &v, sizeof(V)); }

// phase 1 for the particles p .. p + lanes(V) - 1 (tile columns t ..); V = v8 (8 at once) or float (the tile's tail)
template <typename V>
static inline void affine(int64_t p, int64_t t, int64_t P, const float* F, const float* R, const float* C,
                          const float* v, const float* fx, const float* m_, const float* vol, float mu, float lam,
                          float gscale, float dx, float (*qb)[TILE]) {
  V f[9], d[9], tau[9];
  for (int e = 0; e < 9; ++e) { f[e] = ld<V>(F + e * P + p); d[e] = (2.0f * mu) * (f[e] - ld<V>(R + e * P + p)); }
  const V cof0 = f[4] * f[8] - f[5] * f[7], cof1 = f[5] * f[6] - f[3] * f[8], cof2 = f[3] * f[7] - f[4] * f[6];
  const V J = f[0] * cof0 + f[1] * cof1 + f[2] * cof2;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b)
      tau[3 * a + b] = d[3 * a] * f[3 * b] + d[3 * a + 1] * f[3 * b + 1] + d[3 * a + 2] * f[3 * b + 2];
  const V pr = lam * (J - 1.0f) * J;
  tau[0] = tau[0] + pr; tau[4] = tau[4] + pr; tau[8] = tau[8] + pr;
  const V m = ld<V>(m_ + p), gamma = gscale * ld<V>(vol + p);
  const V f0 = ld<V>(fx + p), f1 = ld<V>(fx + P + p), f2 = ld<V>(fx + 2 * P + p);
  st(&qb[0][t], m);
  for (int a = 0; a < 3; ++a) {
    const V A0 = m * ld<V>(C + (3 * a) * P + p) - gamma * tau[3 * a];
    const V A1 = m * ld<V>(C + (3 * a + 1) * P + p) - gamma * tau[3 * a + 1];
    const V A2 = m * ld<V>(C + (3 * a + 2) * P + p) - gamma * tau[3 * a + 2];
    st(&qb[1 + 4 * a][t], m * ld<V>(v + a * P + p) - dx * (A0 * f0 + A1 * f1 + A2 * f2));
    st(&qb[2 + 4 * a][t], dx * A0); st(&qb[3 + 4 * a][t], dx * A1); st(&qb[4 + 4 * a][t], dx * A2);
  }
}

extern "C" int64_t p2g_grid(const float* F, const float* R, const float* C, const float* v, const float* fx,
                            const float* m_, const float* vol, const int64_t* lin, int64_t P,
                            int64_t S0, int64_t S1, int64_t n_nodes, float mu, float lam, float dt, float dx,
                            float inv_dx, float* grid) {
  const float gscale = 4.0f * dt * inv_dx * inv_dx;
  int64_t outside = 0;  // particles whose 3x3x3 stencil leaves the block: skipped, counted, an error in Python
  alignas(64) float qb[13][TILE];
  for (int64_t p0 = 0; p0 < P; p0 += TILE) {
    const int64_t n = P - p0 < TILE ? P - p0 : TILE;
    int64_t t = 0;
    for (; t + 8 <= n; t += 8) affine<v8>(p0 + t, t, P, F, R, C, v, fx, m_, vol, mu, lam, gscale, dx, qb);
    for (; t < n; ++t) affine<float>(p0 + t, t, P, F, R, C, v, fx, m_, vol, mu, lam, gscale, dx, qb);
    for (t = 0; t < n; ++t) {  // phase 2
      const int64_t p = p0 + t, b0 = lin[p];
      if (b0 < 0 || b0 + 2 * S0 + 2 * S1 + 2 >= n_nodes) { ++outside; continue; }
      const v4 c0 = {qb[0][t], qb[1][t], qb[5][t], qb[9][t]};
      const v4 ci = {0.0f, qb[2][t], qb[6][t], qb[10][t]};
      const v4 cj = {0.0f, qb[3][t], qb[7][t], qb[11][t]};
      const v4 ck = {0.0f, qb[4][t], qb[8][t], qb[12][t]};
      float wa[3][3];  // quadratic B-spline weights per axis (grid.bspline_weights' formula and order)
      for (int a = 0; a < 3; ++a) {
        const float f = fx[a * P + p], u0 = 1.5f - f, u1 = f - 1.0f, u2 = f - 0.5f;
        wa[a][0] = 0.5f * (u0 * u0); wa[a][1] = 0.75f - u1 * u1; wa[a][2] = 0.5f * (u2 * u2);
      }
      const v4 c1 = c0 + ck, c2 = c0 + 2.0f * ck;  // the node values at k = 1, 2 (before i ci + j cj)
      const v8 c01 = {c0[0], c0[1], c0[2], c0[3], c1[0], c1[1], c1[2], c1[3]};
      const v8 ci8 = {ci[0], ci[1], ci[2], ci[3], ci[0], ci[1], ci[2], ci[3]};
      const v8 cj8 = {cj[0], cj[1], cj[2], cj[3], cj[0], cj[1], cj[2], cj[3]};
      const v8 w01 = {wa[2][0], wa[2][0], wa[2][0], wa[2][0], wa[2][1], wa[2][1], wa[2][1], wa[2][1]};
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          float* g = grid + 4 * (b0 + i * S0 + j * S1);
          const float wij = wa[0][i] * wa[1][j];
          st(g, ld<v8>(g) + (wij * w01) * ((c01 + (float)i * ci8) + (float)j * cj8));
          st(g + 8, ld<v4>(g + 8) + (wij * wa[2][2]) * ((c2 + (float)i * ci) + (float)j * cj));
        }
    }
  }
  return outside;
}
"""

_LOOP = CppLoop(SOURCE, "p2g_grid", "fused P2G scatter", "the row scatter")


def _library():
    return _LOOP.library()


def p2g_grid_available(*tensors: Tensor) -> bool:
    """Whether :func:`fused_p2g` runs for these inputs: all float32 on the CPU, one torch thread, library built."""
    if not all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors):
        return False
    return torch.get_num_threads() == 1 and bool(_library())


def fused_p2g(
    Ft: Tensor,
    Rt: Tensor,
    Ct: Tensor,
    vt: Tensor,
    fx: Tensor,
    m: Tensor,
    vol: Tensor,
    lin: Tensor,
    n_nodes: int,
    S0: int,
    S1: int,
    mu: float,
    lam: float,
    dt: float,
    dx: float,
    inv_dx: float,
) -> Tensor:
    """The P2G grid (N, 4) ``[m_i, (m v)_i]`` of particles with channel-first Ft, Rt, Ct (9, P), vt, fx (3, P) (the
    weights are computed from fx), masses m and volumes vol (P,) and base nodes lin (P,) int64 on a block grid of
    n_nodes nodes with node-axis strides S0, S1 (call only where :func:`p2g_grid_available`)."""
    P = lin.shape[0]
    args = [t.contiguous() for t in (Ft, Rt, Ct, vt, fx, m, vol)]
    lin = lin.contiguous()
    grid = torch.zeros(n_nodes, 4, dtype=torch.float32)
    ptr = [ctypes.c_void_p(t.data_ptr()) for t in (*args, lin)]
    ints = [ctypes.c_int64(k) for k in (P, S0, S1, n_nodes)]
    floats = [ctypes.c_float(k) for k in (mu, lam, dt, dx, inv_dx)]
    outside = _library().p2g_grid(*ptr, *ints, *floats, ctypes.c_void_p(grid.data_ptr()))
    if outside:  # the row path's index_add_ raises here too; nothing was written out of bounds
        raise IndexError(f"fused P2G: the stencils of {outside} of {P} particles leave the {n_nodes}-node block")
    return grid
