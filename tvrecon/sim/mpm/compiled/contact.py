"""The particle contact's Jacobi passes as one small C++ loop on CPU (the compiled step, ``contact="particle"``).

:func:`tvrecon.sim.mpm.particle_contact.contact_passes` gathers each candidate's velocity from its 27 stencil nodes
(paper eq. 8), computes the impulse that keeps it out of the body (:func:`~tvrecon.sim.mpm.particle_contact.
contact_velocity`) and scatters it back like momentum (eq. 6), ``ITERATIONS`` times. Inductor compiles the scatter
(``index_add``) of the 27 K rows into atomic adds, one element at a time; here each pass is a plain gather loop over
the candidates, then a serial scatter loop, with the same terms in the same order per candidate (the sums over the
27 nodes and over the candidates sharing a node in another order: equal to float32 round-off). A candidate beyond
the contact reach (``phi = +inf``) gets exactly zero force in both, so it is skipped here.

Built once per process with inductor's own C++ toolchain and cache (:class:`.cpp_loop.CppLoop`, as :mod:`.scatter`
and :mod:`.gather`); used only for float32 CPU tensors on one torch thread; anything else, or a failed build, keeps
the inductor kernel.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop, ptr

__all__ = ["SOURCE", "contact_grid_available", "fused_contact"]

#: the C++ source. Per pass: (1) per candidate k, v = sum_o w[o, k] gv[flat[o K + k]] (o slowest, as the (27, K)
#: tables), v = (1 - a) hv + a v (eq. 8) where ``a`` is given, then the force f of ``contact_passes`` (frictionless:
#: clamp(floor_vn - v.n, 0) pull; else the Coulomb branch of ``contact_velocity``) into ``f`` (K, 3) and ``total``;
#: (2) gv[flat[o K + k]] += share[o K + k] f[k]. ``-ffast-math`` of inductor's flags keeps infinities
#: (``-fno-finite-math-only``), so the far candidates' phi = +inf is tested as such.
SOURCE = r"""
#include <cmath>
#include <cstdint>
extern "C" int64_t contact_grid(float* gv, const int64_t* flat, const float* w, const float* share, const float* m,
                                const float* a, const float* hv, const float* phi, const float* n, int64_t K,
                                int64_t n_nodes, int64_t iterations, float dt, float friction, float push_out,
                                float push_cap, float* f, float* total) {
  for (int64_t k = 0; k < 27 * K; ++k)
    if (flat[k] < 0 || flat[k] >= n_nodes) return k + 1;  // a node outside the grid: nothing read or written
  for (int64_t k = 0; k < 3 * K; ++k) total[k] = 0.0f;
  for (int64_t it = 0; it < iterations; ++it) {
    for (int64_t k = 0; k < K; ++k) {
      float* fk = f + 3 * k;
      const float ph = phi[k];
      if (std::isinf(ph)) { fk[0] = fk[1] = fk[2] = 0.0f; continue; }  // beyond the reach: exactly no force
      float v[3] = {0.0f, 0.0f, 0.0f};
      for (int o = 0; o < 27; ++o) {
        const float wo = w[o * K + k];
        const float* g = gv + 3 * flat[o * K + k];
        v[0] += wo * g[0]; v[1] += wo * g[1]; v[2] += wo * g[2];
      }
      float scale = m[k] / dt;
      if (a) {
        const float ak = a[k];
        for (int c = 0; c < 3; ++c) v[c] = (1.0f - ak) * hv[3 * k + c] + ak * v[c];
        scale = ak * m[k] / dt;
      }
      const float* nk = n + 3 * k;
      const float inside = std::fmin(-push_out * std::fmin(ph, 0.0f) / dt, push_cap);
      const float floor_vn = inside - std::fmax(ph, 0.0f) / dt;
      const float vn = v[0] * nk[0] + v[1] * nk[1] + v[2] * nk[2];
      const float dvn = std::fmax(floor_vn - vn, 0.0f);
      if (friction <= 0.0f) {
        for (int c = 0; c < 3; ++c) fk[c] = dvn * (scale * nk[c]);
      } else if (dvn > 0.0f) {  // Coulomb: the tangential velocity loses friction * dvn, not past zero
        float vt[3];
        for (int c = 0; c < 3; ++c) vt[c] = v[c] - vn * nk[c];
        const float norm = std::sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2]);
        const float keep = std::fmax(1.0f - friction * dvn / (norm > 0.0f ? norm : 1.0f), 0.0f);
        for (int c = 0; c < 3; ++c) fk[c] = scale * ((vt[c] * keep + (vn + dvn) * nk[c]) - v[c]);
      } else {
        fk[0] = fk[1] = fk[2] = 0.0f;
      }
      for (int c = 0; c < 3; ++c) total[3 * k + c] += fk[c];
    }
    for (int64_t k = 0; k < K; ++k) {
      const float* fk = f + 3 * k;
      if (fk[0] == 0.0f && fk[1] == 0.0f && fk[2] == 0.0f) continue;  // adds nothing
      for (int o = 0; o < 27; ++o) {
        const float s = share[o * K + k];
        float* g = gv + 3 * flat[o * K + k];
        g[0] += s * fk[0]; g[1] += s * fk[1]; g[2] += s * fk[2];
      }
    }
  }
  return 0;
}
"""

_LOOP = CppLoop(SOURCE, "contact_grid", "fused contact passes", "the inductor kernel")


def contact_grid_available(*tensors: Tensor | None) -> bool:
    """Whether :func:`fused_contact` runs for these inputs (None skipped): all float32 (int64 indices aside) on the
    CPU, one torch thread, library built."""
    present = [t for t in tensors if t is not None]
    if not all(t.device.type == "cpu" and t.dtype in (torch.float32, torch.int64) for t in present):
        return False
    return torch.get_num_threads() == 1 and bool(_LOOP.library())


def fused_contact(
    gv: Tensor,
    flat: Tensor,
    w: Tensor,
    share: Tensor,
    m: Tensor,
    a: Tensor | None,
    hv: Tensor | None,
    phi: Tensor,
    n: Tensor,
    dt: float,
    friction: float,
    push_out: float,
    push_cap: float,
    iterations: int,
) -> tuple[Tensor, Tensor]:
    """:func:`~tvrecon.sim.mpm.particle_contact.contact_passes` with ``iterations`` passes, same arguments: gv (N, 3),
    flat (27 K,) int64, w (27, K, 1), share (27 K, 1), m (K, 1), a (K, 1) and hv (K, 3) or both None, phi (K,), n (K,
    3). Returns the corrected (N, 3) grid velocities (a new tensor) and the (K, 3) force on each candidate (call only
    where :func:`contact_grid_available`)."""
    K = phi.shape[0]
    out = gv.contiguous().clone()
    flat, w, share, m, phi, n = (t.contiguous() for t in (flat, w, share, m, phi, n))
    if (a is None) != (hv is None):
        raise ValueError("fused_contact: give alpha and the hand velocity together, or neither")
    if a is not None:
        a, hv = a.contiguous(), hv.expand(K, 3).contiguous()
    f, total = torch.empty(K, 3, dtype=torch.float32), torch.empty(K, 3, dtype=torch.float32)

    bad = _LOOP.library().contact_grid(
        ptr(out), ptr(flat), ptr(w), ptr(share), ptr(m), ptr(a), ptr(hv), ptr(phi), ptr(n), ctypes.c_int64(K),
        ctypes.c_int64(out.shape[0]), ctypes.c_int64(iterations), ctypes.c_float(dt), ctypes.c_float(friction),
        ctypes.c_float(push_out), ctypes.c_float(push_cap), ptr(f), ptr(total),
    )  # fmt: skip
    if bad:
        raise IndexError(f"fused contact: stencil node {int(flat[bad - 1])} is outside the {out.shape[0]}-node grid")
    return out, total
