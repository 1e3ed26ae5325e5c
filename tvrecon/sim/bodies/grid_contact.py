"""Grid contact: rigid colliders acting on the grid nodes inside them (the simulator contract's collider step of
paper eq. 7: the velocity component into the body removed, Coulomb friction, the momentum removed as the force), on
the solver's block grid."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider

__all__ = ["block_nodes", "collide_grid", "collider_at_block"]


def collide_grid(
    gv: Tensor,
    gm: Tensor,
    colliders: Sequence[Collider | None],
    lo: Tensor,
    D: Sequence[int],
    dx: float,
    dt: float,
    friction: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor]:
    """Remove the velocity component into each collider on grid nodes with sdf < 0 (Coulomb friction optional).

    The collider step of the MLS-MPM grid update (``MLSMPM._grid_update``), on the solver's block grid: B scenes of
    ``D[0] x D[1] x D[2]`` nodes each, scene ``b``'s block starting at global node ``lo[b]``.

    Args:
        gv: (N, 3) grid velocities, N = B * D[0] * D[1] * D[2].
        gm: (N,) grid masses (nodes without mass are left alone).
        colliders: one collider (or None) per scene.
        lo: (B, 3) int64 block origins; D: block dims.
        dx, dt: cell size and time step; friction: Coulomb coefficient (0 = frictionless slip).

    Returns the new (N, 3) grid velocity, the (B, 3) force on the particles (sum m dv / dt per scene) and the (N, 3)
    force of each node (m dv / dt, zero off the colliders)."""
    dtype, device = gv.dtype, gv.device
    B = len(colliders)
    force = torch.zeros(B, 3, dtype=dtype, device=device)
    if all(c is None for c in colliders):
        return gv, force, torch.zeros_like(gv)
    nb = D[0] * D[1] * D[2]
    local = None  # (nb, 3) node offsets in the block, built when a collider needs node positions
    lo_list = lo.tolist()
    pieces = []
    forces = []
    node_forces = []
    mu_f = friction
    for b in range(B):
        vb = gv[b * nb : (b + 1) * nb]
        col = colliders[b]
        if col is None:
            pieces.append(vb)
            node_forces.append(torch.zeros_like(vb))
            forces.append(torch.zeros(3, dtype=dtype, device=device))
            continue
        mb = gm[b * nb : (b + 1) * nb]
        if local is None and not hasattr(col, "at_block"):
            local = block_nodes(D, device)
        sdf, n = collider_at_block(col, lo_list[b], D, dx, dtype, device, local)
        vn = (vb * n).sum(1, keepdim=True)  # (nb, 1)
        hit = (sdf < 0)[:, None] & (vn < 0) & (mb > 0)[:, None]
        vt = vb - vn * n
        if mu_f > 0:
            vt_norm = vt.norm(dim=1, keepdim=True)
            safe = torch.where(vt_norm > 0, vt_norm, torch.ones_like(vt_norm))
            vt = vt * torch.clamp(1.0 + mu_f * vn / safe, min=0.0)
        vb_new = torch.where(hit, vt, vb)
        pieces.append(vb_new)
        dp = mb[:, None] * (vb_new - vb)  # momentum removed by the collider, per node
        node_forces.append(dp / dt)
        forces.append(dp.sum(0) / dt)
    if B == 1:  # one scene: its block is the grid (no copy)
        return pieces[0], torch.stack(forces, 0), node_forces[0]
    return torch.cat(pieces, 0), torch.stack(forces, 0), torch.cat(node_forces, 0)


def block_nodes(D: Sequence[int], device: str | torch.device = "cpu") -> Tensor:
    """(D[0] D[1] D[2], 3) int64 node offsets of a block, i slowest."""
    a0, a1, a2 = (torch.arange(d, device=device) for d in D)
    return torch.stack(torch.meshgrid(a0, a1, a2, indexing="ij"), -1).reshape(-1, 3)


def collider_at_block(
    col: Collider,
    lo: Sequence[int],
    D: Sequence[int],
    dx: float,
    dtype: torch.dtype,
    device: str | torch.device,
    local: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Signed distance (nb,) and unit normal (nb, 3) of ``col`` at the nodes of a block (``D`` nodes from global node
    ``lo``, i slowest), in ``dtype``: a tabulated collider's own nodes (``at_block`` / ``at_nodes``, no
    interpolation), else its ``sdf`` / ``normal`` at the node positions. ``local``: :func:`block_nodes` of ``D``
    when the caller has it (built here otherwise). A table of another spacing than the grid's (a mesh collider
    ``PressConfig.collider_refine`` times finer) is interpolated at the node positions."""
    own = _on_lattice(col, dx)
    if own and hasattr(col, "at_block"):  # tabulated collider: the block's nodes by per-axis indices (no interpolation)
        sdf, n = col.at_block(lo, D, device)
        return sdf.to(dtype), n.to(dtype)
    if local is None:
        local = block_nodes(D, device)
    node = local + torch.tensor(list(lo), device=device)  # (nb, 3) global node indices
    if own and hasattr(col, "at_nodes"):  # tabulated collider: gather at the lattice nodes (no interpolation)
        sdf, n = col.at_nodes(node)
        return sdf.to(dtype), n.to(dtype)
    pos = node.to(dtype) * dx  # (nb, 3) node positions
    return col.sdf(pos), col.normal(pos)


def _on_lattice(col: Collider, dx: float) -> bool:
    """Whether a tabulated collider's nodes are the grid's (its ``dx`` that of the grid); analytic ones are."""
    own = getattr(col, "dx", None)
    return own is None or abs(float(own) - float(dx)) <= 1e-9 * float(dx)
