"""A fused G2P gather for the compiled MLS-MPM step on CPU (opt-in ``compile=True``): one small C++ loop that reads
each particle's 27 node velocities from the ``(N, 3)`` grid, as 9 runs of 3 neighbouring nodes, and updates the
particle (paper eq. 8-11): APIC velocity and affine matrix, the hand's blend, position and deformation gradient.

It is :func:`tvrecon.sim.mpm.compiled.kernels.g2p_update`'s arithmetic with the B-spline weights computed from ``fx``
(:func:`tvrecon.sim.mpm.grid.bspline_weights`), the same terms summed in another order, so equal to the inductor
kernel to float32 round-off. Inductor's loop of that function gathers with scalar indirect loads and recomputes the
weights per channel.

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

#: the C++ source. Per particle: the 3 x 3 axis weights from fx, then for each of the 9 runs (i, j) the 3 nodes'
#: velocities (9 contiguous floats at node ``lin + i S0 + j S1``), summed with the separable weights w_ijk into
#: S[c] = [sum_o w v_c, sum_o w v_c o_i, ... o_j, ... o_k] (GCC / Clang vector extension, as :mod:`.scatter`);
#: C = 4/dx (S[a][1 + b] - v_a fx_b), v = alpha v + (1 - alpha) hv, x += dt v, F += dt C F. ``hv_stride``: 1 for a
#: (3, P) hand velocity, 0 for a (3, 1) one; ``alpha`` null: v is the grid's.
SOURCE = r"""
#include <cstdint>
#include <cstring>
typedef float v4 __attribute__((vector_size(16)));
extern "C" int64_t g2p_grid(const float* gv, const int64_t* lin, const float* fx, const float* x, const float* F,
                            const float* alpha, const float* hv, int64_t hv_stride, int64_t P, int64_t S0_,
                            int64_t S1, int64_t n_nodes, float dt, float inv_dx, float* xo, float* vo, float* Co,
                            float* Fo) {
  int64_t outside = 0;  // particles whose stencil leaves the block: NaN out, counted, an error in Python
  for (int64_t p = 0; p < P; ++p) {
    const int64_t b0 = lin[p];
    float f[3], wa[3][3];
    for (int a = 0; a < 3; ++a) {
      f[a] = fx[a * P + p];
      const float u0 = 1.5f - f[a], u1 = f[a] - 1.0f, u2 = f[a] - 0.5f;
      wa[a][0] = 0.5f * (u0 * u0); wa[a][1] = 0.75f - u1 * u1; wa[a][2] = 0.5f * (u2 * u2);
    }
    if (b0 < 0 || b0 + 2 * S0_ + 2 * S1 + 2 >= n_nodes) {
      ++outside;
      const float nan = __builtin_nanf("");
      for (int e = 0; e < 3; ++e) { xo[e * P + p] = nan; vo[e * P + p] = nan; }
      for (int e = 0; e < 9; ++e) { Co[e * P + p] = nan; Fo[e * P + p] = nan; }
      continue;
    }
    // separable sums, the components c as one 4-float vector: per run (i, j) r0 = sum_k w_k v, rk = sum_k k w_k v;
    // then S0 += w_ij r0, Si += i w_ij r0, Sj += j w_ij r0, Sk += w_ij rk
    v4 S0 = {0.0f, 0.0f, 0.0f, 0.0f}, Si = S0, Sj = S0, Sk = S0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        const float* g = gv + 3 * (b0 + i * S0_ + j * S1);
        v4 n0, n1;  // nodes k = 0, 1 as 16-byte loads (lane 3 is the next float of the run, unused)
        std::memcpy(&n0, g, 16); std::memcpy(&n1, g + 3, 16);
        const v4 n2 = {g[6], g[7], g[8], 0.0f};  // the run's last float may end the grid
        const v4 r0 = (wa[2][0] * n0 + wa[2][1] * n1) + wa[2][2] * n2;
        const v4 rk = wa[2][1] * n1 + (2.0f * wa[2][2]) * n2;
        const float wij = wa[0][i] * wa[1][j];
        S0 += wij * r0;
        if (i) Si += ((float)i * wij) * r0;
        if (j) Sj += ((float)j * wij) * r0;
        Sk += wij * rk;
      }
    const float S[3][4] = {{S0[0], Si[0], Sj[0], Sk[0]}, {S0[1], Si[1], Sj[1], Sk[1]}, {S0[2], Si[2], Sj[2], Sk[2]}};
    float Cn[9], vn[3];
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) Cn[3 * a + b] = (4.0f * inv_dx) * (S[a][1 + b] - S[a][0] * f[b]);
      if (alpha) {
        const float al = alpha[p];
        vn[a] = al * S[a][0] + (1.0f - al) * hv[a * (hv_stride ? P : 1) + (hv_stride ? p : 0)];
      } else {
        vn[a] = S[a][0];
      }
      xo[a * P + p] = x[a * P + p] + dt * vn[a];
      vo[a * P + p] = vn[a];
    }
    float Fr[9];
    for (int e = 0; e < 9; ++e) { Fr[e] = F[e * P + p]; Co[e * P + p] = Cn[e]; }
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        const float cf = Cn[3 * a] * Fr[b] + Cn[3 * a + 1] * Fr[3 + b] + Cn[3 * a + 2] * Fr[6 + b];
        Fo[(3 * a + b) * P + p] = Fr[3 * a + b] + dt * cf;
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
