"""The compiled step's grid update as one C++ loop on CPU (one torch thread), after the fused P2G's ``(N, 4)`` grid.

:func:`tvrecon.sim.mpm.compiled.grid.grid_collide` on the node sums ``[m, m v]`` of
:func:`~tvrecon.sim.mpm.compiled.scatter.fused_p2g`: the grid velocity of paper eq. 7, damping, the colliders'
velocity projection with optional Coulomb friction (:func:`tvrecon.sim.bodies.grid_contact.collide_grid`), each node's
force ``m dv / dt``, each scene's force and the largest velocity component. Through ``torch.compile`` the kernel is
~0.1 ms on the bench scene's block and dynamo's call around it ~0.4 ms; here one ctypes call. The same float32
operations in the same order per node (the scene's force is summed node by node, in another order than inductor's
reduction: equal to round-off); the largest component propagates NaN as ``amax`` does, so the solver's speed check
still sees a diverged grid.

Built once per process with inductor's C++ toolchain (:class:`~tvrecon.sim.mpm.compiled.cpp_loop.CppLoop`); anything
else (float64, CUDA, several threads, the ``(N, 108)`` rows of the inductor P2G, a failed build) keeps the kernel.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop, ptr

__all__ = ["SOURCE", "fused_grid_collide", "grid_loop_available"]

#: per node n of B scenes of N / B nodes: m = G[n, 0]; v = G[n, 1:4] / (m > 0 ? m : 1), times damp when damp != 1;
#: with colliders (sdf, nrm (3, N) not null): vn = v . nrm, a hit (sdf < 0, vn < 0, m > 0) keeps the tangential
#: part vt = v - vn nrm (scaled by max(1 + friction vn / |vt|, 0) when friction > 0); node force m (v' - v) / dt
#: summed per scene; vmax the largest |v'| component (NaN wins).
SOURCE = r"""
#include <cstdint>
#include <cmath>
extern "C" int64_t grid_collide(const float* G, const float* sdf, const float* nrm, int64_t N, int64_t B, float dt,
                                float friction, float damp, float* gv, float* gm, float* nf, float* force,
                                float* vmax) {
  const int64_t nb = N / B;
  float vm = 0.0f;
  for (int64_t b = 0; b < B; ++b) {
    float fs0 = 0.0f, fs1 = 0.0f, fs2 = 0.0f;
    for (int64_t n = b * nb; n < (b + 1) * nb; ++n) {
      const float m = G[4 * n];
      const bool has_mass = m > 0.0f;
      const float sm = has_mass ? m : 1.0f;
      float v0 = G[4 * n + 1] / sm, v1 = G[4 * n + 2] / sm, v2 = G[4 * n + 3] / sm;
      if (damp != 1.0f) { v0 = v0 * damp; v1 = v1 * damp; v2 = v2 * damp; }
      float w0 = v0, w1 = v1, w2 = v2;
      if (sdf) {
        const float n0 = nrm[n], n1 = nrm[N + n], n2 = nrm[2 * N + n];
        const float vn = v0 * n0 + v1 * n1 + v2 * n2;
        if (sdf[n] < 0.0f && vn < 0.0f && has_mass) {
          float t0 = v0 - vn * n0, t1 = v1 - vn * n1, t2 = v2 - vn * n2;
          if (friction > 0.0f) {
            const float tn = std::sqrt(t0 * t0 + t1 * t1 + t2 * t2);
            const float safe = tn > 0.0f ? tn : 1.0f;
            float s = 1.0f + friction * vn / safe;
            s = s < 0.0f ? 0.0f : s;
            t0 = t0 * s; t1 = t1 * s; t2 = t2 * s;
          }
          w0 = t0; w1 = t1; w2 = t2;
        }
        const float f0 = m * (w0 - v0) / dt, f1 = m * (w1 - v1) / dt, f2 = m * (w2 - v2) / dt;
        nf[3 * n] = f0; nf[3 * n + 1] = f1; nf[3 * n + 2] = f2;
        fs0 += f0; fs1 += f1; fs2 += f2;
      }
      gv[3 * n] = w0; gv[3 * n + 1] = w1; gv[3 * n + 2] = w2;
      gm[n] = m;
      const float a0 = std::fabs(w0), a1 = std::fabs(w1), a2 = std::fabs(w2);
      vm = (a0 > vm || a0 != a0) && vm == vm ? a0 : vm;
      vm = (a1 > vm || a1 != a1) && vm == vm ? a1 : vm;
      vm = (a2 > vm || a2 != a2) && vm == vm ? a2 : vm;
    }
    force[3 * b] = fs0; force[3 * b + 1] = fs1; force[3 * b + 2] = fs2;
  }
  *vmax = vm;
  return 0;
}
"""

_LOOP = CppLoop(SOURCE, "grid_collide", "fused grid update", "the compiled grid kernel")


def grid_loop_available(G: Tensor, *tensors: Tensor | None) -> bool:
    """Whether :func:`fused_grid_collide` runs: ``G`` the (N, 4) node sums, it and ``tensors`` (None skipped)
    float32 on the CPU, one torch thread, library built."""
    present = [G, *(t for t in tensors if t is not None)]
    if G.dim() != 2 or G.shape[1] != 4:
        return False
    if not all(t.device.type == "cpu" and t.dtype == torch.float32 for t in present):
        return False
    return torch.get_num_threads() == 1 and bool(_LOOP.library())


def fused_grid_collide(
    G: Tensor, sdf: Tensor | None, nrm: Tensor | None, B: int, dt: float, friction: float, damp: float
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """:func:`tvrecon.sim.mpm.compiled.grid.grid_collide` of the (N, 4) node sums G: sdf (N,) and nrm (3, N) the
    colliders on the nodes (None: no collider in any scene), B scenes of N / B nodes. Returns gv (N, 3), gm (N,),
    node_force (N, 3), force (B, 3) and vmax (0-dim) (call only where :func:`grid_loop_available`)."""
    G = G.contiguous()
    N = G.shape[0]
    if N % B:
        raise ValueError(f"fused_grid_collide: {N} nodes do not split into {B} scenes of equal size")
    collide = sdf is not None and nrm is not None
    if collide:
        sdf, nrm = sdf.contiguous(), nrm.contiguous()
        if sdf.shape != (N,) or nrm.shape != (3, N):
            raise ValueError(f"fused_grid_collide: sdf (N,) and nrm (3, N) for N = {N}, got {sdf.shape}, {nrm.shape}")
    gv, gm = torch.empty(N, 3, dtype=torch.float32), torch.empty(N, dtype=torch.float32)
    nf = torch.empty(N, 3, dtype=torch.float32) if collide else torch.zeros(N, 3, dtype=torch.float32)
    force, vmax = torch.zeros(B, 3, dtype=torch.float32), torch.empty((), dtype=torch.float32)

    _LOOP.library().grid_collide(
        ptr(G), ptr(sdf if collide else None), ptr(nrm if collide else None), ctypes.c_int64(N), ctypes.c_int64(B),
        ctypes.c_float(dt), ctypes.c_float(friction), ctypes.c_float(damp), ptr(gv), ptr(gm), ptr(nf), ptr(force),
        ptr(vmax),
    )  # fmt: skip
    return gv, gm, nf, force, vmax
