"""The compiled step's stencil bases and block index as small C++ loops on CPU (one torch thread).

:func:`tvrecon.sim.mpm.compiled.kernels.stencil_base` and :func:`~tvrecon.sim.mpm.compiled.kernels.block_index` are
two short elementwise kernels; run through ``torch.compile`` each call pays dynamo's guards and wrappers, ~0.4 ms on
this machine, as much as the kernel itself on a small pad (the 48x48x12 bench scene: ~1.1 ms of a 7.8 ms step went
to the three compiled calls' wrappers). Here they are plain loops called through ctypes (~10 us). The arithmetic is
the same float32 operations in the same order (``x * inv_dx``, ``floor(. - 0.5)``, ``. - base``; integer index
arithmetic), so the outputs are bit-identical to the inductor kernels'; ``min`` / ``max`` propagate NaN as
``amin`` / ``amax`` do, so a diverged state still fails the block check.

Built once per process with inductor's C++ toolchain (:class:`~tvrecon.sim.mpm.compiled.cpp_loop.CppLoop`); anything
but float32 CPU tensors on one thread, or a failed build, keeps the compiled kernels.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop, ptr

__all__ = ["SOURCE", "fused_block_index", "fused_stencil_base", "stencil_loops_available"]

#: ``stencil_base``: per scene b of n = P / B contiguous particles, per axis a: Xg = x inv_dx, base = floor(Xg - 0.5),
#: fx = Xg - base, and the scene's min / max of base (NaN wins, as in ``amin`` / ``amax``). ``block_index``: lin =
#: ((b0 - lo0) d0 + (b1 - lo1)) d1 + (b2 - lo2) + scene * d2 in int64, -1 for a non-finite base (P2G's range check
#: then reports it).
SOURCE = r"""
#include <cstdint>
#include <cmath>
extern "C" int64_t stencil_base(const float* x, int64_t P, int64_t B, float inv_dx, float* base, float* fx,
                                float* lo, float* hi) {
  const int64_t n = P / B;
  for (int a = 0; a < 3; ++a) {
    const float* xa = x + a * P;
    float* ba = base + a * P;
    float* fa = fx + a * P;
    for (int64_t b = 0; b < B; ++b) {
      float mn = INFINITY, mx = -INFINITY;
      bool nan = false;
      for (int64_t p = b * n; p < (b + 1) * n; ++p) {
        const float Xg = xa[p] * inv_dx;
        const float bf = std::floor(Xg - 0.5f);
        ba[p] = bf;
        fa[p] = Xg - bf;
        nan |= bf != bf;
        mn = bf < mn ? bf : mn;
        mx = bf > mx ? bf : mx;
      }
      lo[a * B + b] = nan ? NAN : mn;
      hi[a * B + b] = nan ? NAN : mx;
    }
  }
  return 0;
}

extern "C" int64_t block_index(const float* base, const int64_t* lo, int64_t P, int64_t B, int64_t d0, int64_t d1,
                               int64_t d2, int64_t* lin) {
  const int64_t n = P / B;
  for (int64_t b = 0; b < B; ++b) {
    const int64_t l0 = lo[b], l1 = lo[B + b], l2 = lo[2 * B + b], off = b * d2;
    for (int64_t p = b * n; p < (b + 1) * n; ++p) {
      const float f0 = base[p], f1 = base[P + p], f2 = base[2 * P + p];
      if (!(std::isfinite(f0) && std::isfinite(f1) && std::isfinite(f2))) { lin[p] = -1; continue; }
      lin[p] = (((int64_t)f0 - l0) * d0 + ((int64_t)f1 - l1)) * d1 + ((int64_t)f2 - l2) + off;
    }
  }
  return 0;
}
"""

_LOOP = CppLoop(SOURCE, "stencil_base", "stencil and block-index loops", "the compiled kernels", also=("block_index",))


def _library():
    return _LOOP.library()


def stencil_loops_available(*tensors: Tensor) -> bool:
    """Whether :func:`fused_stencil_base` and :func:`fused_block_index` run for these inputs: float32 / int64 CPU
    tensors, one torch thread, library built."""
    if not all(t.device.type == "cpu" and t.dtype in (torch.float32, torch.int64) for t in tensors):
        return False
    return torch.get_num_threads() == 1 and bool(_library())


def fused_stencil_base(xt: Tensor, inv_dx: float, B: int = 1) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`tvrecon.sim.mpm.compiled.kernels.stencil_base`: xt (3, P) float32 positions of B scenes of P / B
    contiguous particles -> base_f, fx (3, P) and the per-scene bounds lo_f, hi_f (3, B) of base_f (call only where
    :func:`stencil_loops_available`)."""
    xt = xt.contiguous()
    P = xt.shape[1]
    if P % B:
        raise ValueError(f"fused_stencil_base: {P} particles do not split into {B} scenes of equal size")
    base, fx = torch.empty(3, P, dtype=torch.float32), torch.empty(3, P, dtype=torch.float32)
    lo, hi = torch.empty(3, B, dtype=torch.float32), torch.empty(3, B, dtype=torch.float32)
    _library().stencil_base(
        ptr(xt), ctypes.c_int64(P), ctypes.c_int64(B), ctypes.c_float(inv_dx), *map(ptr, (base, fx, lo, hi))
    )
    return base, fx, lo, hi


def fused_block_index(base_f: Tensor, lo: Tensor, D: list[int]) -> Tensor:
    """:func:`tvrecon.sim.mpm.compiled.kernels.block_index`: base_f (3, P) float32 base nodes of B scenes, lo (3, B)
    int64 block origins, D the block dims [D0, D1, D2] (the kernel's ``dims`` are ``[D1, D2, D0 D1 D2]``) -> (P,)
    int64 linear block index (-1 where a base is not finite)."""
    base_f, lo = base_f.contiguous(), lo.contiguous()
    P, B = base_f.shape[1], lo.shape[1]
    if P % B:
        raise ValueError(f"fused_block_index: {P} particles do not split into {B} scenes of equal size")
    d0, d1, d2 = int(D[1]), int(D[2]), int(D[0]) * int(D[1]) * int(D[2])
    lin = torch.empty(P, dtype=torch.int64)
    _library().block_index(
        ptr(base_f), ptr(lo), ctypes.c_int64(P), ctypes.c_int64(B), ctypes.c_int64(d0), ctypes.c_int64(d1),
        ctypes.c_int64(d2), ptr(lin),
    )  # fmt: skip
    return lin
