"""The fixed-step polar decomposition of the compiled step as one small C++ loop on CPU, eight particles at a time,
stopping as soon as all eight have converged.

:func:`tvrecon.sim.mpm.compiled.kernels.polar_fixed` (R of F = R S for the stress of paper eq. 2-3, fixed-corotated)
runs all ``NEWTON_ITERS`` scaled Newton steps for every particle: a particle that has converged is frozen, but its
steps are still computed. Most of a pad's particles are strained by a few percent and converge in two. Here eight
neighbouring particles (one 8-float vector per matrix entry, GCC / Clang vector extension, read straight from the
channel-first ``(9, P)`` layout) take the same steps in the same order, and the loop leaves them once all eight are
frozen: the remaining steps would not change them, so R is ``polar_fixed``'s to float32 round-off (the same
operations, but a multiplication by one reciprocal where it divides nine entries by ``det`` and by ``gs``: the
divisions were most of the loop's time). A particle not converged after ``n_iter`` steps (or with a
step that is not finite) makes the 0-dim ``converged`` False, as ``polar_fixed``'s, and the caller falls back to the
iterating decomposition.

Built once per process with inductor's own C++ toolchain and cache (:class:`.cpp_loop.CppLoop`); used only for
float32 CPU tensors on one torch thread; anything else, or a failed build, keeps the inductor kernel.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop

__all__ = ["SOURCE", "fused_polar", "polar_grid_available"]

#: the C++ source: per group of 8 particles (the last padded with identity matrices), ``polar_fixed``'s step:
#: cof = cofactor(X) (its row order), det, X^-T = cof (1 / det), gs = (|X^-T|^2 / |X|^2)^(1/4),
#: X' = 0.5 (gs X + X^-T (1 / gs)), delta = max |X' - X| (NaN kept), X = done ? X : X', done |= delta < stop; until
#: every lane is done or ``n_iter`` steps. Returns the number of particles not converged. The square roots go through
#: AVX's vector instruction where the compiler targets it (``-march=native`` in inductor's flags), else lane by lane.
SOURCE = r"""
#include <cstdint>
#include <cstring>
#if defined(__AVX__)
#include <immintrin.h>
#endif
typedef float v8 __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));
static inline v8 vsqrt(v8 x) {
#if defined(__AVX__)
  return (v8)_mm256_sqrt_ps((__m256)x);
#else
  v8 r;
  for (int l = 0; l < 8; ++l) r[l] = __builtin_sqrtf(x[l]);
  return r;
#endif
}
static inline v8 vabs(v8 x) {
  v8i bits;
  std::memcpy(&bits, &x, 32);
  bits &= 0x7fffffff;
  std::memcpy(&x, &bits, 32);
  return x;
}
static inline bool all_set(v8i m) {
  for (int l = 0; l < 8; ++l)
    if (!m[l]) return false;
  return true;
}
extern "C" int64_t polar_fixed8(const float* F, int64_t P, int64_t n_iter, float stop, float* R) {
  int64_t failed = 0;
  for (int64_t p0 = 0; p0 < P; p0 += 8) {
    const int64_t lanes = P - p0 < 8 ? P - p0 : 8;
    v8 X[9];
    for (int e = 0; e < 9; ++e) {
      if (lanes == 8) {
        std::memcpy(&X[e], F + e * P + p0, 32);
      } else {  // the tail: identity matrices in the unused lanes (converged at their first step)
        const float id = (e % 4 == 0) ? 1.0f : 0.0f;
        for (int l = 0; l < 8; ++l) X[e][l] = l < lanes ? F[e * P + p0 + l] : id;
      }
    }
    v8i done = {0, 0, 0, 0, 0, 0, 0, 0};
    for (int64_t it = 0; it < n_iter && !all_set(done); ++it) {
      const v8 c[9] = {
          X[4] * X[8] - X[5] * X[7], X[5] * X[6] - X[3] * X[8], X[3] * X[7] - X[4] * X[6],
          X[7] * X[2] - X[8] * X[1], X[8] * X[0] - X[6] * X[2], X[6] * X[1] - X[7] * X[0],
          X[1] * X[5] - X[2] * X[4], X[2] * X[3] - X[0] * X[5], X[0] * X[4] - X[1] * X[3]};
      const v8 det = X[0] * c[0] + X[1] * c[1] + X[2] * c[2];
      const v8 rdet = 1.0f / det;  // two divisions a step instead of 18 (each within an ulp of polar_fixed's)
      v8 inv[9];
      for (int e = 0; e < 9; ++e) inv[e] = c[e] * rdet;
      v8 n_inv = inv[0] * inv[0], n_x = X[0] * X[0];
      for (int e = 1; e < 9; ++e) { n_inv += inv[e] * inv[e]; n_x += X[e] * X[e]; }
      const v8 gs = vsqrt(vsqrt(n_inv / n_x));
      const v8 rgs = 1.0f / gs;
      v8 delta;
      for (int e = 0; e < 9; ++e) {
        const v8 xn = 0.5f * (gs * X[e] + inv[e] * rgs);
        const v8 d = vabs(xn - X[e]);
        if (e == 0) delta = d;
        else delta = ((d > delta) | (d != d)) ? d : delta;  // torch.maximum: NaN wins
        X[e] = done ? X[e] : xn;
      }
      done |= (delta < stop);
    }
    for (int e = 0; e < 9; ++e) {
      if (lanes == 8) std::memcpy(R + e * P + p0, &X[e], 32);
      else for (int l = 0; l < lanes; ++l) R[e * P + p0 + l] = X[e][l];
    }
    for (int l = 0; l < lanes; ++l) failed += done[l] ? 0 : 1;
  }
  return failed;
}
"""

_LOOP = CppLoop(SOURCE, "polar_fixed8", "fused polar loop", "the inductor kernel")


def polar_grid_available(Ft: Tensor) -> bool:
    """Whether :func:`fused_polar` runs for ``Ft``: float32 on the CPU, one torch thread, library built."""
    if Ft.device.type != "cpu" or Ft.dtype != torch.float32:
        return False
    return torch.get_num_threads() == 1 and bool(_LOOP.library())


def fused_polar(Ft: Tensor, stop: float, n_iter: int) -> tuple[Tensor, Tensor]:
    """:func:`~tvrecon.sim.mpm.compiled.kernels.polar_fixed` of ``Ft`` (9, P): R as (9, P) and a 0-dim bool tensor,
    every particle converged within ``n_iter`` steps (call only where :func:`polar_grid_available`)."""
    if Ft.dim() != 2 or Ft.shape[0] != 9:
        raise ValueError(f"fused_polar: F must be (9, P) channel-first, got {tuple(Ft.shape)}")
    Ft = Ft.contiguous()
    P = Ft.shape[1]
    R = torch.empty_like(Ft)
    failed = _LOOP.library().polar_fixed8(
        ctypes.c_void_p(Ft.data_ptr()), ctypes.c_int64(P), ctypes.c_int64(n_iter), ctypes.c_float(stop),
        ctypes.c_void_p(R.data_ptr()),
    )  # fmt: skip
    return R, torch.tensor(failed == 0)
