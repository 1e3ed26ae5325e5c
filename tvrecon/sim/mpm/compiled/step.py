"""The no-grad MLS-MPM step with the per-particle parts fused by ``torch.compile`` (opt-in: ``MLSMPM(compile=True)``
or ``PressConfig(compile=True)``; kernels in :mod:`.kernels`).

Same order as :meth:`tvrecon.sim.mpm.solver.MLSMPM._step` (P2G, grid update, G2P: paper eq. 5-11). The scatter
differs in layout only: each particle's 108 contributions are one contiguous row of a node-major ``(N, 108)`` table
(``index_add_`` along the nodes, ~1.9x faster than the eager step's ``(108, N)`` columns), whose 27 offsets are
then summed by the compiled ``grid_collide`` (another summation order: equal to round-off), which also does the grid
update and the colliders (their fields looked up only when a block moves, ``compiled.grid.ColliderFields``).
On CPU with one torch thread, float32, P2G is instead one C++ loop that adds each particle's stencil straight onto
the ``(N, 4)`` grid (:mod:`.scatter`; paper touches ~1.3x faster in one process, equal to round-off).
G2P gathers the 27 node velocities from the ``(N, 3)`` grid inside its kernel. The block bounds and each particle's
node index are compiled too (``stencil_weights``, ``block_index``) when the scenes are contiguous blocks.
The state comes back as views of the kernels' channel-first buffers (``CF_VIEWS``), so the next fused step reads it
without a copy. With ``MPMConfig(contact="particle")`` the grid update has no colliders;
:func:`tvrecon.sim.mpm.particle_contact.particle_contact_grid` then finds the particles near a body (eager) and corrects
the grid velocities with its contact passes (one compiled kernel, ``contact_passes``) before the compiled G2P.
The reading's force field (``MLSMPM.last_particle_force``) is one compiled gather too (:func:`particle_force`; with
particle contact, the contact's own particle forces).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider
from tvrecon.sim.mpm.block_grid import Stencil, Transfer, block_dims, block_layout, share_node_force
from tvrecon.sim.mpm.compiled.backend import CompiledKernels
from tvrecon.sim.mpm.compiled.gather import fused_g2p, g2p_grid_available
from tvrecon.sim.mpm.compiled.grid import ColliderFields
from tvrecon.sim.mpm.compiled.grid_loop import fused_grid_collide, grid_loop_available
from tvrecon.sim.mpm.compiled.kernels import NEWTON_ITERS
from tvrecon.sim.mpm.compiled.polar import fused_polar, polar_grid_available
from tvrecon.sim.mpm.compiled.scatter import fused_p2g, p2g_grid_available
from tvrecon.sim.mpm.compiled.stencil import fused_block_index, fused_stencil_base, stencil_loops_available
from tvrecon.sim.mpm.materials import polar_decomposition
from tvrecon.sim.mpm.particle_contact import MeshStackCache, particle_contact_grid
from tvrecon.sim.mpm.state import MPMConfig, ParticleState

__all__ = ["CF_VIEWS", "FusedStep", "fused_step", "particle_force"]

#: the compiled step returns its (P, 3) / (P, 3, 3) state tensors as views of its channel-first (3, P) / (9, P)
#: buffers (same values, transposed strides), so that the next compiled step reads them without a copy. False:
#: contiguous copies (the eager layout).
CF_VIEWS = True


def _cf_state(state: ParticleState, xt: Tensor, vt: Tensor, Ct: Tensor, Ft: Tensor) -> ParticleState:
    P = xt.shape[1]
    if CF_VIEWS:
        return replace(state, x=xt.T, v=vt.T, C=Ct.T.view(P, 3, 3), F=Ft.T.view(P, 3, 3))
    return replace(
        state,
        x=xt.T.contiguous(),
        v=vt.T.contiguous(),
        C=Ct.T.reshape(P, 3, 3).contiguous(),
        F=Ft.T.reshape(P, 3, 3).contiguous(),
    )


class FusedStep(NamedTuple):
    """What a compiled step returns; the solver stores all but ``state``."""

    state: ParticleState  # the new state (x, v, C, F as channel-first views, see CF_VIEWS)
    force: Tensor  # (B, 3) force the collider(s) exerted on each scene's particles (``MLSMPM.last_force``)
    transfer: Transfer  # the step's transfer, for ``MLSMPM.last_particle_force``
    particle_force: Tensor | None  # (P, 3) particle contact's force per particle (contact="particle"), else None
    vmax: Tensor  # 0-dim: the fastest grid node's largest velocity component, for ``MLSMPM``'s speed check
    dims: list[int]  # the block dims the step used (``MLSMPM.last_dims``)
    polar_ok: Tensor | None  # 0-dim bool: the fixed-step polar converged (``defer_polar``: left to the caller's read)


def _grid_update(
    kernels: CompiledKernels,
    fields: ColliderFields,
    G: Tensor,
    colliders: list[Collider | None],
    st: Stencil,
    cfg: MPMConfig,
    dt: float,
) -> tuple[Tensor, Tensor, Transfer, Tensor]:
    """Node sums, grid velocity and colliders in one compiled kernel (``grid_collide``), as ``MLSMPM._grid_update``.
    Returns the (N, 3) node velocities, the (B, 3) collider force, the step's transfer and the 0-dim largest node
    velocity component (the solver checks it, :func:`~tvrecon.sim.mpm.block_grid.check_grid_speed`)."""
    D = st.D
    dx = 1.0 / cfg.n_grid
    sdf, nrm = fields(colliders, st.lo, D, dx, G.dtype, G.device)
    damp = math.exp(-cfg.damping * dt) if cfg.damping > 0 else 1.0
    S0, S1 = D[1] * D[2], D[2]
    if grid_loop_available(G, sdf, nrm):  # CPU, one thread, the fused P2G's (N, 4) sums: one C++ loop (grid_loop)
        gv, gm, node_force, force, vmax = fused_grid_collide(G, sdf, nrm, len(colliders), dt, float(cfg.friction), damp)
    else:
        gv, gm, node_force, force, vmax = kernels(
            "grid", G, S0, S1, sdf, nrm, len(colliders), dt, float(cfg.friction), damp
        )
    return gv, force, Transfer(st.lin, None, gm, node_force, (S0, S1), st.fx.T), vmax


def fused_step(
    kernels: CompiledKernels,
    fields: ColliderFields,
    state: ParticleState,
    colliders: list[Collider | None],
    hand_velocity: Tensor | None,
    alpha: Tensor | None,
    B: int,
    block: int | None,
    cfg: MPMConfig,
    dt: float,
    mu: float | Tensor,
    lam: float | Tensor,
    chunk: int,
    o_int: Tensor,
    stack: MeshStackCache | None = None,
    dims: list[int] | None = None,
    padded: bool = False,
    defer_polar: bool = False,
    exact_polar: bool = False,
    hand_cf: Tensor | None = None,
) -> FusedStep:
    """One no-grad step with the compiled ``kernels``; the collider ``fields`` remember the colliders' sdf on the
    block grid between steps. ``state`` ... ``block`` as :meth:`tvrecon.sim.mpm.solver.MLSMPM._step`; ``cfg``: the
    solver's config (grid, damping, friction, contact), ``dt`` its step, ``mu`` / ``lam`` its Lame parameters,
    ``chunk`` the particles per compiled P2G call (0 = all), ``o_int`` the (27, 3) int64 stencil offsets, ``stack``
    the solver's stacked mesh colliders of the particle contact (None: searched scene by scene).

    The eager step's deferred checks (``MLSMPM.defer_checks``, the GPU's layout): ``dims`` are the block dims read
    by the caller with the last step's read (None: read here, one host sync), ``padded`` when they were given with a
    margin instead (``MLSMPM.trust_next``: the indices are clamped into the block, as ``grid.block_index`` does);
    ``defer_polar`` leaves the fixed-step polar's convergence to the caller (``FusedStep.polar_ok``) instead of a read
    here; ``exact_polar`` takes the iterating polar decomposition (the caller's rerun of a step that did not
    converge); ``hand_cf``: the (3, P) channel-first copy of a (P, 3) ``hand_velocity`` when the caller keeps one
    (None: made here)."""
    k = kernels
    x = state.x
    P = x.shape[0]
    dtype, device = x.dtype, x.device
    dx, inv_dx = 1.0 / cfg.n_grid, float(cfg.n_grid)
    # channel-first copies (no copy when the state came from a compiled step: see _cf_state)
    xt, Ft = x.T.contiguous(), state.F.reshape(P, 9).T.contiguous()
    if state.batch is None or block is not None:  # contiguous scenes (every press): bounds and index per scene
        loops = stencil_loops_available(xt)  # CPU, one thread: two plain C++ loops, no dynamo call (compiled.stencil)
        base_t, fx, lo_f, hi_f = fused_stencil_base(xt, inv_dx, B) if loops else k("stencil", xt, inv_dx, B)
        D = block_dims(lo_f.T, hi_f.T, B) if dims is None else list(dims)
        lo_t = lo_f.to(torch.int64)  # (3, B)
        if padded:  # dims taken on trust: a base node outside the block is moved to its edge (the caller reruns)
            top = torch.tensor(D, dtype=base_t.dtype, device=device)[:, None, None] - 3.0  # (3, 1, 1)
            low = lo_f[:, :, None]  # (3, B, 1)
            base_t = torch.minimum(torch.maximum(base_t.view(3, B, -1), low), low + top).view(3, -1)
        if loops:
            lin = fused_block_index(base_t, lo_t, D)
        else:
            strides = torch.tensor([D[1], D[2], D[0] * D[1] * D[2]], dtype=torch.int64, device=device)
            lin = k("index", base_t, lo_t, strides)
        lo = lo_t.T
    else:
        base_t, fx, _, _ = k("stencil", xt, inv_dx, 1)
        lo, lin, D = block_layout(base_t.T, state.batch, B, block)
    n_nodes = B * D[0] * D[1] * D[2]
    st = Stencil(fx.T, None, lo, lin, D, n_nodes, chunk if chunk > 0 else P)  # no (27, P) weights: from fx

    stop = (8.0 * torch.finfo(dtype).eps) ** 0.5  # polar_decomposition's default tol = 4 eps
    polar_ok = None
    if exact_polar:
        Rt = polar_decomposition(state.F).reshape(P, 9).T.contiguous()
    else:
        if polar_grid_available(Ft):  # CPU, one thread: 8 particles at a time, until they converge (compiled.polar)
            Rt, converged = fused_polar(Ft, stop, NEWTON_ITERS)
        else:
            Rt, converged = k("polar", Ft, stop)
        if defer_polar:
            polar_ok = converged
        elif not bool(converged):  # rare: a particle needs more Newton steps (or F is singular: eager raises)
            Rt = polar_decomposition(state.F).reshape(P, 9).T.contiguous()
    mu, lam = float(mu), float(lam)
    Ct, vt = state.C.reshape(P, 9).T.contiguous(), state.v.T.contiguous()
    S0, S1 = D[1] * D[2], D[2]
    if p2g_grid_available(x, state.mass, state.volume):  # CPU, one thread: the fused C++ scatter (compiled.scatter)
        G = fused_p2g(Ft, Rt, Ct, vt, fx, state.mass, state.volume, lin, n_nodes, S0, S1, mu, lam, dt, dx, inv_dx)
    else:
        G = torch.zeros(n_nodes, 108, dtype=dtype, device=device)  # per base node: the 4 x 27 sums of its particles
        chunk = st.chunk
        for s0 in range(0, P, chunk):
            n = min(chunk, P - s0)
            contrib = k("p2g", Ft, Rt, Ct, vt, fx, state.mass, state.volume, s0, n, mu, lam, dt, dx, inv_dx)
            G.index_add_(0, lin[s0 : s0 + n], contrib)  # one contiguous row of 108 per particle
    pforce = None
    if cfg.contact == "particle":  # opt-in: the grid without colliders, then the eager particle contact
        gv, force, transfer, pforce, vmax = _particle_contact(
            k, fields, state, G, st, colliders, hand_velocity, alpha, B, block, cfg, dt, stack
        )
        gv = gv.contiguous()
    else:
        gv, force, transfer, vmax = _grid_update(k, fields, G, colliders, st, cfg, dt)
        gv = gv.contiguous()  # (N, 3)
    offs = o_int[::3, 0] * S0 + o_int[::3, 1] * S1  # (9,) node-axis offsets of the runs (i, j, k = 0..2)
    runs = gv.as_strided((gv.shape[0] - 2, 9), (3, 1))  # row n: nodes n, n+1, n+2 (a view; base + 2 S0 + 2 S1 < N - 2)
    if hand_velocity is None:
        hvt = None
    elif hand_velocity.dim() == 1:
        hvt = hand_velocity[:, None]
    else:
        hvt = hand_velocity.T.contiguous() if hand_cf is None else hand_cf
    if alpha is not None and hvt is None:
        hvt = torch.zeros(3, 1, dtype=dtype, device=device)
    if g2p_grid_available(gv, xt, Ft, alpha, hvt):  # CPU, one thread: the fused C++ gather (compiled.gather)
        xn, vn, Cn, Fn = fused_g2p(gv, lin, fx, xt, Ft, alpha, hvt, S0, S1, dt, inv_dx)
    else:
        xn, vn, Cn, Fn = k("g2p", runs, offs, lin, fx, xt, Ft, alpha, hvt, dt, inv_dx)
    return FusedStep(_cf_state(state, xn, vn, Cn, Fn), force, transfer, pforce, vmax, D, polar_ok)


def _particle_contact(
    kernels: CompiledKernels,
    fields: ColliderFields,
    state: ParticleState,
    G: Tensor,
    st: Stencil,
    colliders: list[Collider | None],
    hand_velocity: Tensor | None,
    alpha: Tensor | None,
    B: int,
    block: int | None,
    cfg: MPMConfig,
    dt: float,
    stack: MeshStackCache | None = None,
) -> tuple[Tensor, Tensor, Transfer, Tensor, Tensor]:
    """The grid side of a compiled step with ``MPMConfig(contact="particle")``, in :meth:`MLSMPM._step`'s order: the
    compiled grid update without colliders (paper eq. 7), then
    :func:`tvrecon.sim.mpm.particle_contact.particle_contact_grid` with the compiled contact passes. G: the P2G sums,
    (N, 4) or (N, 108) rows; st: the fused stencil (w (27, P), the eager ``lin``, ``D`` and ``lo``).
    Returns the corrected (N, 3) grid velocities for the compiled G2P, the (B, 3) contact force, the transfer and
    the (P, 3) particle forces, and the largest node velocity component before the contact."""
    gv, _, transfer, vmax = _grid_update(kernels, fields, G, [None] * B, st, cfg, dt)
    gv, force, pforce = particle_contact_grid(
        state,
        st,
        gv.contiguous(),
        transfer.node_mass,
        colliders,
        hand_velocity,
        alpha,
        B,
        block,
        dt,
        1.0 / cfg.n_grid,
        cfg.friction,
        kernels,
        stack,
        vmax,
    )
    return gv, force, transfer, pforce, vmax


def particle_force(kernels: CompiledKernels, transfer: Transfer, mass: Tensor, o_int: Tensor) -> Tensor:
    """``MLSMPM.last_particle_force`` of a compiled solver: :func:`tvrecon.sim.mpm.block_grid.share_node_force` as one
    compiled gather of the per-mass node forces (``compiled.kernels.share_force``; the same terms summed in another
    order, without the eager ``(27, P, 3)`` gathered copy). mass: (P,). Returns (P, 3), detached."""
    lin, w, gm, node_force, (S0, S1), fx = transfer
    differentiable = (w is not None and w.requires_grad) or node_force.requires_grad or mass.requires_grad
    if mass.shape != lin.shape or differentiable or fx is None:  # eager: raises on a wrong shape and
        return share_node_force(transfer, mass, o_int)  # keeps the graph of a differentiable step
    per_mass = (node_force / torch.where(gm > 0, gm, torch.ones_like(gm))[:, None]).contiguous()  # (N, 3)
    runs = per_mass.as_strided((per_mass.shape[0] - 2, 9), (3, 1))  # as in fused_step's G2P
    offs = o_int[::3, 0] * S0 + o_int[::3, 1] * S1
    return kernels("share", runs, offs, lin, fx, mass.detach().to(fx))
