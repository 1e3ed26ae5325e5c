"""The grid side of the compiled MLS-MPM step (opt-in ``compile=True``): node sums, grid velocity and colliders in
one fused kernel, fed by collider fields that are looked up only when a scene's block moves.

- :func:`grid_collide`: the 27 stencil offsets of the scattered P2G rows summed onto their nodes
  (:func:`tvrecon.sim.mpm.compiled.kernels.node_sums`), the grid velocity of paper eq. 7, damping, the collider velocity
  projection of :func:`tvrecon.sim.bodies.grid_contact.collide_grid` (optional Coulomb friction), the force of each
  node and of each scene, and the largest grid speed (the solver's explosion check); written as plain elementwise torch
  on channel-first ``(3, N)`` node rows so that inductor fuses it into a few loops.
- :class:`ColliderFields`: the colliders' signed distance and normals on the block grid, ``(N,)`` and ``(3, N)``,
  kept while every scene's block origin and the block dims stay the same (a press moves its block by a cell every
  ~10 steps: ~93% of paper-touch steps reuse them). The values are those of the eager lookup
  (:func:`tvrecon.sim.bodies.grid_contact.collider_at_block`); tabulated and analytic colliders alike.

Equal to the eager grid update to float32 round-off (the per-scene force is summed in another order).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider
from tvrecon.sim.bodies.grid_contact import block_nodes, collider_at_block
from tvrecon.sim.mpm.compiled.kernels import node_sums

__all__ = ["ColliderFields", "grid_collide"]


def grid_collide(
    G: Tensor,
    S0: int,
    S1: int,
    sdf: Tensor | None,
    nrm: Tensor | None,
    B: int,
    dt: float,
    friction: float,
    damp: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Grid update of one step from the scattered P2G rows.

    G: (N, 108) P2G rows per base node (:func:`node_sums`), or the (N, 4) node sums themselves
    (:func:`tvrecon.sim.mpm.compiled.scatter.fused_p2g`); S0, S1: node-axis strides of i and j; sdf (N,) and
    nrm (3, N): the colliders on the nodes (:class:`ColliderFields`; None: no collider in any scene); B scenes of
    N / B nodes each; damp: ``exp(-damping dt)`` (1: none).

    Returns gv (N, 3) node velocities after the colliders, gm (N,) node masses, node_force (N, 3) ``m dv / dt``,
    force (B, 3) its per-scene sums and vmax (0-dim) the largest ``|gv|`` component.
    """
    grid = G.T if G.shape[1] == 4 else node_sums(G, S0, S1)  # (4, N)
    gm = grid[0]
    has_mass = gm > 0
    safe_m = torch.where(has_mass, gm, torch.ones_like(gm))
    v = [grid[1 + a] / safe_m for a in range(3)]  # paper eq. 7, zero where m = 0
    if damp != 1.0:
        v = [e * damp for e in v]
    if sdf is None or nrm is None:
        gv = torch.stack(v, 1)
        zero = torch.zeros_like(gv)
        return gv, gm, zero, zero.new_zeros(B, 3), gv.abs().amax()
    n = nrm.unbind(0)
    vn = v[0] * n[0] + v[1] * n[1] + v[2] * n[2]
    hit = (sdf < 0) & (vn < 0) & has_mass
    vt = [e - vn * ne for e, ne in zip(v, n)]
    if friction > 0:
        vt_norm = torch.sqrt(vt[0] * vt[0] + vt[1] * vt[1] + vt[2] * vt[2])
        safe = torch.where(vt_norm > 0, vt_norm, torch.ones_like(vt_norm))
        scale = torch.clamp(1.0 + friction * vn / safe, min=0.0)
        vt = [e * scale for e in vt]
    v_new = [torch.where(hit, t, e) for t, e in zip(vt, v)]
    node_force = torch.stack([gm * (e1 - e0) / dt for e1, e0 in zip(v_new, v)], 1)  # (N, 3)
    force = node_force.view(B, -1, 3).sum(1)
    gv = torch.stack(v_new, 1)
    vmax = torch.maximum(torch.maximum(v_new[0].abs().amax(), v_new[1].abs().amax()), v_new[2].abs().amax())
    return gv, gm, node_force, force, vmax


class ColliderFields:
    """The colliders' signed distance (N,) and unit normals (3, N) on the block grid of a step, remembered per scene
    (collider, block origin, block dims) and for the whole grid of the last step."""

    def __init__(self) -> None:
        self._scene: dict[int, tuple[Collider, tuple[int, ...], tuple[int, ...], Tensor, Tensor]] = {}
        self._last: tuple[list[Collider | None], list[list[int]], tuple[int, ...], Tensor, Tensor] | None = None

    def __call__(
        self,
        colliders: Sequence[Collider | None],
        lo: Tensor,
        D: Sequence[int],
        dx: float,
        dtype: torch.dtype,
        device: torch.device,
    ) -> tuple[Tensor | None, Tensor | None]:
        """sdf (N,) and normals (3, N) of ``colliders`` (one per scene) on blocks of dims ``D`` from origins ``lo``
        (B, 3); ``(None, None)`` when every collider is None. Scenes without a collider get sdf 1 (no contact)."""
        if all(c is None for c in colliders):
            return None, None
        lo_list = lo.tolist()
        dims = tuple(int(d) for d in D)
        last = self._last
        if (
            last is not None
            and last[2] == dims
            and last[1] == lo_list
            and len(last[0]) == len(colliders)
            and all(a is b for a, b in zip(last[0], colliders))
            and last[3].dtype == dtype
        ):
            return last[3], last[4]
        nb = dims[0] * dims[1] * dims[2]
        local = None
        sdfs, nrms = [], []
        for b, col in enumerate(colliders):
            if col is None:
                sdfs.append(torch.ones(nb, dtype=dtype, device=device))
                nrms.append(torch.zeros(3, nb, dtype=dtype, device=device))
                continue
            key = tuple(lo_list[b])
            hit = self._scene.get(b)
            if hit is not None and hit[0] is col and hit[1] == key and hit[2] == dims and hit[3].dtype == dtype:
                sdfs.append(hit[3])
                nrms.append(hit[4])
                continue
            if local is None and not hasattr(col, "at_block"):
                local = block_nodes(dims, device)
            sdf, n = collider_at_block(col, key, dims, dx, dtype, device, local)
            sdf, nt = sdf.contiguous(), n.T.contiguous()
            self._scene[b] = (col, key, dims, sdf, nt)
            sdfs.append(sdf)
            nrms.append(nt)
        if len(sdfs) == 1:
            sdf_all, nrm_all = sdfs[0], nrms[0]
        else:
            sdf_all, nrm_all = torch.cat(sdfs, 0), torch.cat(nrms, 1)
        self._last = (list(colliders), lo_list, dims, sdf_all, nrm_all)
        return sdf_all, nrm_all
