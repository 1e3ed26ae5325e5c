"""The particle contact of stacked mesh colliders as one C++ loop on CPU: search, set-up and passes (compiled step).

A compiled step with ``contact="particle"`` and one mesh collider per scene ran three kernels and a compaction for its
contact: the prefilter of every particle (``near_blocks``: the least node sdf of its cell), ``torch.nonzero`` of it,
the lookup and set-up of the candidates (``mesh_contact``: their trilinear sdf and normal, 27 stencil nodes, weights
and impulse shares as (27, K) tables) and the passes (:mod:`.contact`). On a paper pad the prefilter keeps ~2.3x the
particles within the reach (a table cell's least node is up to a cell diagonal below its points), and the set-up of
those far candidates was most of the contact's cost. Here one loop over the particles does the prefilter and, for
those it keeps, the lookup, and keeps only the particles whose sdf is within the reach
(:func:`~tvrecon.sim.mpm.contact_reach.speed_reach`; the others would get exactly zero impulse); their stencil and
shares are computed once, then the ``ITERATIONS`` Jacobi passes run as in :mod:`.contact`, all without a Python
call between them and without a host sync of the tensor library.

The arithmetic is that of ``near_blocks``, ``stacked_sdf_normal`` (float64 cell coordinates, float32 weights, the
corners summed pairwise as ``corner_sum``), ``contact_setup`` and ``contact_passes``, term by term, so the readings
equal the kernels' to float32 round-off (``tests/sim/mpm/test_mesh_contact_loop.py``). Candidates come in particle
order, as ``torch.nonzero`` gives them. Built once per process with inductor's C++ toolchain
(:class:`.cpp_loop.CppLoop`); used only for float32 CPU tensors on one torch thread with the press's contiguous scenes;
anything else, or a failed build, keeps the kernels.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from tvrecon.sim.bodies.mesh_stack import MeshStack
from tvrecon.sim.mpm.compiled.contact import SOURCE as CONTACT_SOURCE
from tvrecon.sim.mpm.compiled.cpp_loop import CppLoop, ptr

__all__ = ["SOURCE", "fused_mesh_contact", "mesh_contact_loop_available", "mesh_search"]

#: the C++ source: (1) per scene b and particle p of its block, the prefilter (the least node sdf of the cell of
#: ``near_blocks``, its margins), then the trilinear sdf and normal of ``stacked_sdf_normal`` and the keep test ``phi
#: < reach``; (2) per kept candidate its 27 stencil nodes ``lin[p] + shifts[o]``, weights (``bspline_weights``) and
#: shares ``w dt / m_i``; (3) the passes: :mod:`.contact`'s ``contact_grid``, whose source comes first. Returns the
#: number of candidates K, or -(k + 1) when candidate k has a stencil node outside the grid (the grid then unchanged).
SOURCE = (
    CONTACT_SOURCE
    + r"""
#include <vector>
extern "C" int64_t mesh_search(
    const float* x, int64_t sp, int64_t sa, int64_t B, int64_t block, const float* lo32, const int64_t* cdims,
    const int64_t* coff, const float* cmin, double tdx, const float* reach_p, const double* cell, const int64_t* ints,
    const float* table, const float* box, const float* up, int64_t* cand, float* phi, float* nrm) {
  const float reach = *reach_p;
  const float tdxf = (float)tdx;
  int64_t K = 0;
  for (int64_t b = 0; b < B; ++b) {
    const float* lo = lo32 + 3 * b;
    const int64_t* d = cdims + 3 * b;
    const double* c = cell + 9 * b;
    const int64_t* in = ints + 6 * b;
    const float* bx = box + 6 * b;
    for (int64_t q = 0; q < block; ++q) {
      const int64_t p = b * block + q;
      const float xp[3] = {x[p * sp], x[p * sp + sa], x[p * sp + 2 * sa]};
      int64_t i0[3];
      bool finite = true;
      for (int a = 0; a < 3; ++a) {  // near_blocks: the particle's cell of the cell-minimum table
        float fl = std::floor(xp[a] / tdxf - lo[a]);
        if (!(fl == fl)) finite = false;
        fl = fl > 0.0f ? fl : 0.0f;
        const float top = (float)(d[a] - 1);
        i0[a] = (int64_t)(fl < top ? fl : top);
      }
      if (!finite) continue;  // a NaN position: the kernels' comparisons drop it too
      const float least = cmin[coff[b] + (i0[0] * d[1] + i0[1]) * d[2] + i0[2]];
      if (!(least - 1e-5f * std::fabs(least) - 1e-3f * tdxf < reach)) continue;
      // stacked_sdf_normal: float64 cell coordinates, float32 weights, corners (cx, cy, cz), cx slowest
      int64_t j[2][3];
      float ww[2][3];
      for (int a = 0; a < 3; ++a) {
        double g = (double)xp[a] / tdx - c[a];
        g = g > 0.0 ? g : 0.0;
        g = g < c[3 + a] ? g : c[3 + a];
        double fl = std::floor(g);
        fl = fl < c[6 + a] ? fl : c[6 + a];
        const int64_t lo_i = (int64_t)fl;
        j[0][a] = lo_i;
        j[1][a] = lo_i + 1 < in[a] ? lo_i + 1 : in[a];
        const float f = (float)(g - (double)lo_i);
        ww[0][a] = 1.0f - f;
        ww[1][a] = f;
      }
      float t[8][4];
      for (int cx = 0; cx < 2; ++cx)
        for (int cy = 0; cy < 2; ++cy)
          for (int cz = 0; cz < 2; ++cz) {
            const int corner = cx * 4 + cy * 2 + cz;
            const float w = ww[cx][0] * ww[cy][1] * ww[cz][2];
            const int64_t row = (j[cx][0] * in[3] + j[cy][1]) * in[4] + j[cz][2] + in[5];
            for (int e = 0; e < 4; ++e) t[corner][e] = w * table[4 * row + e];
          }
      float out[4];
      for (int e = 0; e < 4; ++e) {  // corner_sum: (0 + 4, 1 + 5, 2 + 6, 3 + 7), then (h0 + h2, h1 + h3), then both
        const float h0 = t[0][e] + t[4][e], h1 = t[1][e] + t[5][e], h2 = t[2][e] + t[6][e], h3 = t[3][e] + t[7][e];
        out[e] = (h0 + h2) + (h1 + h3);
      }
      float dd[3];
      for (int a = 0; a < 3; ++a) {
        float cl = xp[a] > bx[a] ? xp[a] : bx[a];
        cl = cl < bx[3 + a] ? cl : bx[3 + a];
        dd[a] = xp[a] - cl;
      }
      const float ph = out[0] + std::sqrt(dd[0] * dd[0] + dd[1] * dd[1] + dd[2] * dd[2]);
      if (!(ph < reach)) continue;  // beyond the reach: exactly no impulse this step
      const float nn = std::sqrt(out[1] * out[1] + out[2] * out[2] + out[3] * out[3]);
      float* nk = nrm + 3 * K;
      for (int a = 0; a < 3; ++a) nk[a] = nn > 1e-12f ? out[1 + a] / (nn > 1e-12f ? nn : 1e-12f) : up[a];
      phi[K] = ph;
      cand[K] = p;
      ++K;
    }
  }
  return K;
}

extern "C" int64_t mesh_contact_loop(
    const float* x, int64_t sp, int64_t sa, int64_t B, int64_t block, const float* lo32, const int64_t* cdims,
    const int64_t* coff, const float* cmin, double tdx, const float* reach_p, const double* cell, const int64_t* ints,
    const float* table, const float* box, const float* up, const int64_t* lin, const float* fxt, int64_t P,
    const int64_t* shifts, const float* node_mass, int64_t n_nodes, const float* mass, const float* alpha,
    const float* hv, int64_t hv_rows, float* gv, int64_t iterations, float dt, float friction, float push_out,
    float push_cap, int64_t* cand, float* phi, float* nrm, float* total) {
  const int64_t K = mesh_search(x, sp, sa, B, block, lo32, cdims, coff, cmin, tdx, reach_p, cell, ints, table, box,
                                up, cand, phi, nrm);
  // contact_setup of the K candidates: stencil nodes, weights, shares w_ip dt / m_i, masses, alpha, hand velocity
  std::vector<int64_t> flat(27 * K);
  std::vector<float> w(27 * K), share(27 * K), m(K), ak(alpha ? K : 0), hk(alpha ? 3 * K : 0), f(3 * K);
  for (int64_t k = 0; k < K; ++k) {
    const int64_t p = cand[k];
    float wa[3][3];
    for (int a = 0; a < 3; ++a) {
      const float fa = fxt[a * P + p];
      wa[a][0] = 0.5f * ((1.5f - fa) * (1.5f - fa));
      wa[a][1] = 0.75f - (fa - 1.0f) * (fa - 1.0f);
      wa[a][2] = 0.5f * ((fa - 0.5f) * (fa - 0.5f));
    }
    for (int o = 0; o < 27; ++o) {
      const int64_t node = lin[p] + shifts[o];
      if (node < 0 || node >= n_nodes) return -(k + 1);
      const float wo = wa[0][o / 9] * wa[1][(o / 3) % 3] * wa[2][o % 3];
      const float gm = node_mass[node];
      const float inv_m = gm > 0.0f ? 1.0f / gm : 0.0f;
      flat[o * K + k] = node;
      w[o * K + k] = wo;
      share[o * K + k] = wo * (dt * inv_m);
    }
    m[k] = mass[p];
    if (alpha) {
      ak[k] = alpha[p];
      const float* h = hv + 3 * (hv_rows == 1 ? 0 : p);
      for (int a = 0; a < 3; ++a) hk[3 * k + a] = h[a];
    }
  }
  // the passes: compiled.contact's loop (its source comes first in this one)
  contact_grid(gv, flat.data(), w.data(), share.data(), m.data(), alpha ? ak.data() : nullptr,
               alpha ? hk.data() : nullptr, phi, nrm, K, n_nodes, iterations, dt, friction, push_out, push_cap,
               f.data(), total);
  return K;
}
"""
)

_LOOP = CppLoop(SOURCE, "mesh_contact_loop", "fused mesh contact loop", "the mesh contact kernels", ("mesh_search",))


def mesh_contact_loop_available(x: Tensor, B: int, block: int | None, *tensors: Tensor | None) -> bool:
    """Whether :func:`fused_mesh_contact` runs: the press's contiguous scenes (``block`` particles each), float32
    positions and tensors (int64 indices aside, None skipped) on the CPU, one torch thread, library built."""
    if block is None or x.shape[0] != B * block:
        return False
    present = [t for t in (x, *tensors) if t is not None]
    if not all(t.device.type == "cpu" and t.dtype in (torch.float32, torch.int64) for t in present):
        return False
    return x.dtype == torch.float32 and torch.get_num_threads() == 1 and bool(_LOOP.library())


def fused_mesh_contact(
    gv: Tensor,
    node_mass: Tensor,
    lin: Tensor,
    fxt: Tensor,
    shifts: Tensor,
    x: Tensor,
    mass: Tensor,
    alpha: Tensor | None,
    hand_velocity: Tensor | None,
    stack: MeshStack,
    reach: Tensor,
    block: int,
    dt: float,
    friction: float,
    push_out: float,
    push_cap: float,
    iterations: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """The particle contact of the B = ``len(stack.colliders)`` scenes of ``block`` contiguous particles each, as
    ``particle_contact_grid``'s compiled branch runs it with a search to ``reach`` (0-dim).

    Args:
        gv: (N, 3) grid velocities before the contact (not written). node_mass: (N,). lin: (P,) int64 base node of
            each particle. fxt: (3, P) its offset from the base node in cells. shifts: (27,) int64 stencil offsets.
        x: (P, 3) positions. mass: (P,). alpha: (P,) or None (paper eq. 8). hand_velocity: (3,), (1, 3) or (P, 3),
            with ``alpha``. stack: the scenes' mesh colliders. dt, friction, push_out, push_cap, iterations: as
            :func:`~tvrecon.sim.mpm.particle_contact.contact_passes`.
    Returns:
        the corrected (N, 3) grid velocities (a new tensor), the (K,) int64 candidates within the reach (in particle
        order) and the (K, 3) collider force on each (sum over the passes).
    """
    P = x.shape[0]
    out = gv.contiguous().clone()
    hv, rows = None, 0
    if alpha is not None:
        hv = torch.zeros(1, 3) if hand_velocity is None else hand_velocity.reshape(-1, 3).float().contiguous()
        rows = hv.shape[0]
        if rows not in (1, P):
            raise ValueError(f"fused_mesh_contact: hand velocity of {rows} rows for {P} particles")
        alpha = alpha.float().contiguous()
    cand, phi, nrm = torch.empty(P, dtype=torch.int64), torch.empty(P), torch.empty(P, 3)
    total = torch.empty(P, 3)
    lin, fxt, shifts, node_mass, mass = (t.contiguous() for t in (lin, fxt, shifts, node_mass, mass))
    reach32 = reach.detach().to(torch.float32).reshape(1).contiguous()
    K = _LOOP.library().mesh_contact_loop(
        *_search_args(x, stack, reach32, block), ptr(lin), ptr(fxt), ctypes.c_int64(P), ptr(shifts), ptr(node_mass),
        ctypes.c_int64(out.shape[0]), ptr(mass), ptr(alpha), ptr(hv), ctypes.c_int64(rows), ptr(out),
        ctypes.c_int64(iterations), ctypes.c_float(dt), ctypes.c_float(friction), ctypes.c_float(push_out),
        ctypes.c_float(push_cap), ptr(cand), ptr(phi), ptr(nrm), ptr(total),
    )  # fmt: skip
    if K < 0:
        p = int(cand[-K - 1])
        raise IndexError(f"fused mesh contact: particle {p}'s stencil leaves the {out.shape[0]}-node grid")
    return out, cand[:K], total[:K]


def mesh_search(x: Tensor, stack: MeshStack, reach: Tensor, block: int) -> tuple[Tensor, Tensor, Tensor]:
    """The search of :func:`fused_mesh_contact` alone: the (K,) int64 particles of ``x`` (P, 3) within ``reach``
    (0-dim) of their scene's mesh (``block`` contiguous particles a scene), in particle order, their (K,) signed
    distances and (K, 3) unit normals (``MeshStack.sdf_normal``'s, to float32 round-off). Call only where
    :func:`mesh_contact_loop_available`."""
    P = x.shape[0]
    cand, phi, nrm = torch.empty(P, dtype=torch.int64), torch.empty(P), torch.empty(P, 3)
    reach32 = reach.detach().to(torch.float32).reshape(1).contiguous()
    K = _LOOP.library().mesh_search(*_search_args(x, stack, reach32, block), ptr(cand), ptr(phi), ptr(nrm))
    return cand[:K], phi[:K], nrm[:K]


def _search_args(x: Tensor, stack: MeshStack, reach32: Tensor, block: int) -> list:
    """The search's leading C arguments: the positions in place (any strides: a compiled step's channel-first copy
    is not copied back), the scenes, the prefilter's and the lookup's tables, the reach (the caller's (1,) float32
    tensor, alive until the call returns)."""
    cell, ints, table, box, up = stack.lookup_tables(torch.float32)
    return [
        ptr(x), ctypes.c_int64(x.stride(0)), ctypes.c_int64(x.stride(1)), ctypes.c_int64(len(stack.colliders)),
        ctypes.c_int64(block), ptr(stack.lo_index32), ptr(stack.cmin_dims), ptr(stack.cmin_offset), ptr(stack.cmin),
        ctypes.c_double(stack.dx), ptr(reach32), ptr(cell), ptr(ints), ptr(table), ptr(box), ptr(up),
    ]  # fmt: skip
