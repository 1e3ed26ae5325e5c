"""A fused G2P gather for the compiled MLS-MPM step on CPU (opt-in ``compile=True``): one small C++ loop that reads
each particle's 27 node velocities from the ``(N, 3)`` grid, as 9 runs of 3 neighbouring nodes, and updates the
particle (paper eq. 8-11): APIC velocity and affine matrix, the hand's blend, position and deformation gradient.

It is :func:`tvrecon.sim.mpm.compiled.kernels.g2p_update`'s arithmetic with the B-spline weights computed from ``fx``
(:func:`tvrecon.sim.mpm.block_grid.bspline_weights`), the same terms summed in another order and fused into FMAs, so
equal to the inductor kernel to float32 round-off. Inductor's loop of that function gathers with scalar indirect loads
and recomputes the weights per channel. The particles go in tiles of 256: the node sums one particle at a time, then the
particle update (C, v, x, F: a third of the loop's time when it was done per particle) 8 particles at a time on the
channel-first arrays (a paper step's gather 1.8x faster, ``benchmarks/bench_cpp_loops.py``).

Built once per process with inductor's own C++ toolchain and cache, like :mod:`.scatter`; used only for float32 CPU
tensors on one torch thread (the loop is serial; with more threads inductor's loop runs in parallel); anything else,
or a failed build, keeps the inductor kernel.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop, ptr

__all__ = ["SOURCE", "fused_g2p", "g2p_grid_available"]

#: the C++ source, in tiles of 256 particles. Phase A, per particle: the 3 x 3 axis weights from fx, then for each of
#: the 9 runs (i, j) the 3 nodes' velocities (9 contiguous floats at node ``lin + i S0 + j S1``), summed with the
#: separable weights w_ijk into S[c] = [sum_o w v_c, sum_o w v_c o_i, ... o_j, ... o_k] (the components c as one
#: 4-float vector, GCC / Clang vector extension), kept in a (12, 256) tile. Phase B, 8 particles at a time (8-float
#: vectors over the channel-first arrays; the tile's last < 8 one by one, the same code on floats):
#: C = 4/dx (S[a][1 + b] - v_a fx_b), v = alpha v + (1 - alpha) hv, x += dt v, F += dt C F. ``hv_stride``: 1 for a
#: (3, P) hand velocity, 0 for a (3, 1) one; ``alpha`` null: v is the grid's. Products are fused into FMAs
#: (``fp-contract=fast`` for this source only: inductor builds with it off), one more source of round-off.
SOURCE = r"""
#pragma GCC optimize("fp-contract=fast")
#include <cstdint>
#include <cstring>
typedef float v4 __attribute__((vector_size(16)));
typedef float v8 __attribute__((vector_size(32)));
typedef int32_t i4 __attribute__((vector_size(16)));
constexpr int64_t TILE = 256;
// lanes 1, 2, 3, 3 of a 4-float vector (GCC's and Clang's own spellings of the shuffle)
#if defined(__clang__)
static inline v4 down1(v4 a) { return __builtin_shufflevector(a, a, 1, 2, 3, 3); }
#else
static inline v4 down1(v4 a) { return __builtin_shuffle(a, (i4){1, 2, 3, 3}); }
#endif
template <typename V> static inline V ld(const float* p) { V r; std::memcpy(&r, p, sizeof(V)); return r; }
template <typename V> static inline void st(float* p, V v) { std::memcpy(p, &v, sizeof(V)); }

// phase B for the particles p .. p + lanes(V) - 1 (tile columns t ..): C, v, x, F from their node sums Sb (12, TILE),
// Sb[4a + m][t] = S[a][m]; V = v8 (8 particles at once) or float (the tile's tail). MODE 0: v is the grid's;
// 1: blended with one hand velocity; 2: with one per particle
template <typename V, int MODE>
static inline void finish(int64_t p, int64_t t, int64_t P, const float (*Sb)[TILE], const float* fx, const float* x,
                          const float* F, const float* alpha, const float* hv, float dt, float c4, float* xo,
                          float* vo, float* Co, float* Fo) {
  const V f[3] = {ld<V>(fx + p), ld<V>(fx + P + p), ld<V>(fx + 2 * P + p)};
  V Cn[9], al{};
  if (MODE) al = ld<V>(alpha + p);
  for (int a = 0; a < 3; ++a) {
    const V s = ld<V>(&Sb[4 * a][t]);
    for (int b = 0; b < 3; ++b) Cn[3 * a + b] = c4 * (ld<V>(&Sb[4 * a + 1 + b][t]) - s * f[b]);
    V vn = s;
    if (MODE == 1) vn = al * s + (1.0f - al) * hv[a];
    if (MODE == 2) vn = al * s + (1.0f - al) * ld<V>(hv + a * P + p);
    st(xo + a * P + p, ld<V>(x + a * P + p) + dt * vn);
    st(vo + a * P + p, vn);
  }
  V Fr[9];
  for (int e = 0; e < 9; ++e) { Fr[e] = ld<V>(F + e * P + p); st(Co + e * P + p, Cn[e]); }
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const V cf = Cn[3 * a] * Fr[b] + Cn[3 * a + 1] * Fr[3 + b] + Cn[3 * a + 2] * Fr[6 + b];
      st(Fo + (3 * a + b) * P + p, Fr[3 * a + b] + dt * cf);
    }
}

template <int MODE>
static void finish_tile(int64_t p0, int64_t n, int64_t P, const float (*Sb)[TILE], const float* fx, const float* x,
                        const float* F, const float* alpha, const float* hv, float dt, float c4, float* xo,
                        float* vo, float* Co, float* Fo) {
  int64_t t = 0;
  for (; t + 8 <= n; t += 8) finish<v8, MODE>(p0 + t, t, P, Sb, fx, x, F, alpha, hv, dt, c4, xo, vo, Co, Fo);
  for (; t < n; ++t) finish<float, MODE>(p0 + t, t, P, Sb, fx, x, F, alpha, hv, dt, c4, xo, vo, Co, Fo);
}

static inline bool inside(int64_t b0, int64_t S0, int64_t S1, int64_t n_nodes) {
  return b0 >= 0 && b0 + 2 * S0 + 2 * S1 + 2 < n_nodes;
}

extern "C" int64_t g2p_grid(const float* gv, const int64_t* lin, const float* fx, const float* x, const float* F,
                            const float* alpha, const float* hv, int64_t hv_stride, int64_t P, int64_t S0_,
                            int64_t S1, int64_t n_nodes, float dt, float inv_dx, float* xo, float* vo, float* Co,
                            float* Fo) {
  int64_t outside = 0;  // particles whose stencil leaves the block: NaN out, counted, an error in Python
  alignas(64) float Sb[12][TILE];
  for (int64_t p0 = 0; p0 < P; p0 += TILE) {
    const int64_t n = P - p0 < TILE ? P - p0 : TILE;
    int64_t bad = 0;
    for (int64_t t = 0; t < n; ++t) {  // phase A
      const int64_t p = p0 + t, b0 = lin[p];
      if (!inside(b0, S0_, S1, n_nodes)) {
        ++bad;
        for (int e = 0; e < 12; ++e) Sb[e][t] = 0.0f;
        continue;
      }
      float wa[3][3];
      for (int a = 0; a < 3; ++a) {
        const float f = fx[a * P + p], u0 = 1.5f - f, u1 = f - 1.0f, u2 = f - 0.5f;
        wa[a][0] = 0.5f * (u0 * u0); wa[a][1] = 0.75f - u1 * u1; wa[a][2] = 0.5f * (u2 * u2);
      }
      // per run (i, j): r0 = sum_k w_k v, rk = sum_k k w_k v; then A0 += w_ij r0, Ai += i w_ij r0, Aj += j w_ij r0,
      // Ak += w_ij rk
      v4 A0 = {0.0f, 0.0f, 0.0f, 0.0f}, Ai = A0, Aj = A0, Ak = A0;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          const float* g = gv + 3 * (b0 + i * S0_ + j * S1);
          // nodes k = 0, 1, 2 as 16-byte loads at floats 0, 3 and 5 (lane 3 unused; the last load ends at the run's
          // last float, which may end the grid, and is shifted down one lane)
          const v4 n0 = ld<v4>(g), n1 = ld<v4>(g + 3), n2 = down1(ld<v4>(g + 5));
          const v4 r0 = wa[2][0] * n0 + wa[2][1] * n1 + wa[2][2] * n2;
          const v4 rk = wa[2][1] * n1 + (2.0f * wa[2][2]) * n2;
          const float wij = wa[0][i] * wa[1][j];
          A0 += wij * r0;
          if (i) Ai += ((float)i * wij) * r0;
          if (j) Aj += ((float)j * wij) * r0;
          Ak += wij * rk;
        }
      for (int a = 0; a < 3; ++a) {
        Sb[4 * a][t] = A0[a]; Sb[4 * a + 1][t] = Ai[a]; Sb[4 * a + 2][t] = Aj[a]; Sb[4 * a + 3][t] = Ak[a];
      }
    }
    const float c4 = 4.0f * inv_dx;
    if (!alpha) finish_tile<0>(p0, n, P, Sb, fx, x, F, alpha, hv, dt, c4, xo, vo, Co, Fo);
    else if (!hv_stride) finish_tile<1>(p0, n, P, Sb, fx, x, F, alpha, hv, dt, c4, xo, vo, Co, Fo);
    else finish_tile<2>(p0, n, P, Sb, fx, x, F, alpha, hv, dt, c4, xo, vo, Co, Fo);
    if (bad) {
      outside += bad;
      const float nan = __builtin_nanf("");
      for (int64_t t = 0; t < n; ++t) {
        const int64_t p = p0 + t;
        if (inside(lin[p], S0_, S1, n_nodes)) continue;
        for (int e = 0; e < 3; ++e) { xo[e * P + p] = nan; vo[e * P + p] = nan; }
        for (int e = 0; e < 9; ++e) { Co[e * P + p] = nan; Fo[e * P + p] = nan; }
      }
    }
  }
  return outside;
}
"""

_LOOP = CppLoop(SOURCE, "g2p_grid", "fused G2P gather", "the inductor kernel")


def _library():
    return _LOOP.library()


def g2p_grid_available(*tensors: Tensor | None) -> bool:
    """Whether :func:`fused_g2p` runs for these inputs (None skipped): all float32 on the CPU, one torch thread,
    library built."""
    present = [t for t in tensors if t is not None]
    if not all(t.device.type == "cpu" and t.dtype == torch.float32 for t in present):
        return False
    return torch.get_num_threads() == 1 and bool(_library())


def fused_g2p(
    gv: Tensor,
    lin: Tensor,
    fx: Tensor,
    xt: Tensor,
    Ft: Tensor,
    alpha: Tensor | None,
    hvt: Tensor | None,
    S0: int,
    S1: int,
    dt: float,
    inv_dx: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`~tvrecon.sim.mpm.compiled.kernels.g2p_update` on the (N, 3) grid velocities gv with node-axis strides
    S0, S1: base nodes lin (P,) int64, channel-first fx, xt (3, P), Ft (9, P), alpha (P,) or None, hvt (3, P) or
    (3, 1) hand velocity or None (zero; without alpha it is not used, as in ``g2p_update``). Returns x, v (3, P), C,
    F (9, P) (call only where :func:`g2p_grid_available`)."""
    P = lin.shape[0]
    if alpha is None:
        hvt = None
    gv, lin, fx, xt, Ft = (t.contiguous() for t in (gv, lin, fx, xt, Ft))
    if alpha is not None:
        alpha = alpha.contiguous()
        hvt = torch.zeros(3, 1, dtype=torch.float32) if hvt is None else hvt.contiguous()
        if hvt.shape not in ((3, 1), (3, P)):
            raise ValueError(f"fused_g2p: hand velocity must be (3, 1) or (3, {P}), got {tuple(hvt.shape)}")
    out = [torch.empty(k, P, dtype=torch.float32) for k in (3, 3, 9, 9)]

    outside = _library().g2p_grid(
        ptr(gv), ptr(lin), ptr(fx), ptr(xt), ptr(Ft), ptr(alpha), ptr(hvt),
        ctypes.c_int64(0 if hvt is None or hvt.shape[1] == 1 else 1), ctypes.c_int64(P), ctypes.c_int64(S0),
        ctypes.c_int64(S1), ctypes.c_int64(gv.shape[0]), ctypes.c_float(dt), ctypes.c_float(inv_dx), *map(ptr, out),
    )  # fmt: skip
    if outside:  # G2P of a stencil outside the block: the P2G before it raised too; nothing was read out of bounds
        raise IndexError(f"fused G2P: the stencils of {outside} of {P} particles leave the {gv.shape[0]}-node block")
    return out[0], out[1], out[2], out[3]
