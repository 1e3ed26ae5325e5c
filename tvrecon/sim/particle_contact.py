"""Particle-level rigid contact (opt-in ``MPMConfig(contact="particle")``, issue 15 item 1).

The default collider (:func:`tvrecon.sim.colliders.collide_grid`) acts on grid nodes whose signed distance is
negative. A node carries mass from particles up to 1.5 cells away, so contact starts before the particles reach the
body, and a curved body acts through whole node rings at once (one-cell steps that depend on where the body sits
between node planes). Here the contact is decided at the particles, whose positions are known to sub-cell accuracy,
with the signed distance evaluated exactly at them, and its impulse is applied through the grid:

- a particle at signed distance ``phi >= 0`` moving along the outward normal ``n`` at ``v_n = v . n`` (its G2P
  velocity, paper eq. 8) may approach the body by at most ``phi`` this step: ``v_n' = max(v_n, -phi / dt)`` (a
  speculative contact: it lands on the surface instead of crossing it); a particle already inside (``phi < 0``) is
  sent back out by ``PUSH_OUT`` of its depth: ``v_n' = max(v_n, -PUSH_OUT phi / dt)``;
- the tangential velocity loses ``friction * (v_n' - v_n)`` (Coulomb; 0 = frictionless slip, as on the grid);
- the impulse ``J_p = m_p (v' - v)`` is scattered to the grid with the transfer weights, like the momentum of P2G
  (paper eq. 6), and G2P is done again (:func:`particle_contact_step`). ``J_p / dt`` is the collider's force on
  particle p; per scene it sums to ``MLSMPM.last_force``, and momentum is conserved as on the grid.

Contact therefore starts when a particle (not a node) reaches the surface, whatever the body's offset from the node
planes, and the contact area grows particle by particle (the pad's spacing, 0.5 cells by default). This is the
grid-mediated particle impulse of the contact literature (particle-level detection with the response through the
grid, cf. the penalty contacts of DiffTactile and the particle-grid compatibility of MLS-MPM's CPIC, Hu et al.
2018): detecting on particles but correcting only their velocities would leave the grid free below them (see
:func:`particle_contact_step`). Everything is torch, batched over scenes (each scene's particles meet only its own
collider), device-agnostic and differentiable where the collider's ``sdf`` and ``normal`` are (the analytic ones,
and ``MeshCollider`` by trilinear interpolation). It costs a second G2P per step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from .colliders import Collider
from .mpm_grid import Stencil, stencil_offsets

if TYPE_CHECKING:
    from .mpm import MLSMPM, ParticleState

__all__ = ["CONTACT_MODES", "collide_particles", "particle_contact_step", "stencil_nodes", "scene_slices"]

#: ``MPMConfig.contact`` values: "grid" (the default node collider, the simulator contract) or "particle" (here).
CONTACT_MODES = ("grid", "particle")

#: Fraction of its depth a particle found inside a body is moved back out per step (Baumgarte-style correction of the
#: penetration the grid smoothing lets through). 0.5: measured 0.15 cells of penetration at 1.5 cells depth (64-grid
#: tests' scene), against 0.29 with 0.2 and 0.08 with 1.0; exponents alike, the force 10% higher at 1.0.
PUSH_OUT = 0.5

#: The push-out never asks for more than this many cells per step (a particle pushed deep inside by a sharp feature
#: comes out over several steps instead of being shot out).
PUSH_CAP_CELLS = 0.05

#: Jacobi passes of the grid-mediated particle impulse per step (:func:`particle_contact_step`).
ITERATIONS = 3


def scene_slices(batch: Tensor | None, B: int, block: int | None) -> list[slice | Tensor]:
    """The particles of each of the B scenes: slices when the layout is contiguous (``block`` particles per scene),
    else (P,) boolean masks of ``batch``."""
    if batch is None:
        return [slice(None)]
    if block is not None:
        return [slice(b * block, (b + 1) * block) for b in range(B)]
    return [batch == b for b in range(B)]


def collide_particles(
    x: Tensor,
    v: Tensor,
    mass: Tensor,
    colliders: Sequence[Collider | None],
    scenes: Sequence[slice | Tensor],
    dt: float,
    friction: float = 0.0,
    push_out: float = 0.0,
    push_cap: float = math.inf,
) -> tuple[Tensor, Tensor, Tensor]:
    """Speculative non-penetration of each scene's particles against its rigid collider (see the module docstring).

    Args:
        x: (P, 3) particle positions at the start of the step (domain units).
        v: (P, 3) particle velocities after G2P (paper eq. 8), before the position update.
        mass: (P,) particle masses.
        colliders: one collider (or None) per scene.
        scenes: the particles of each scene (:func:`scene_slices`), same length as ``colliders``.
        dt: time step. friction: Coulomb coefficient (0 = frictionless slip).
        push_out: fraction of its depth a particle found inside is sent back out this step (0: it only stops).
        push_cap: the largest outward normal velocity the push-out asks for (domain units / s).

    Returns:
        the corrected (P, 3) velocity, the (B, 3) force of each collider on its scene's particles and the (P, 3)
        force on each particle (``m_p (v' - v) / dt``; zero away from the bodies).
    """
    if x.dim() != 2 or x.shape[1] != 3 or v.shape != x.shape:
        raise ValueError(f"x and v must be (P, 3) tensors of one shape, got {tuple(x.shape)} and {tuple(v.shape)}")
    if mass.shape != x.shape[:1]:
        raise ValueError(f"mass must be (P,) = ({x.shape[0]},), got {tuple(mass.shape)}")
    if len(scenes) != len(colliders):
        raise ValueError(f"need one particle selection per collider, got {len(scenes)} for {len(colliders)}")
    B = len(colliders)
    force = torch.zeros(B, 3, dtype=v.dtype, device=v.device)
    if all(c is None for c in colliders):
        return v, force, torch.zeros_like(v)
    pieces = []
    for b, col in enumerate(colliders):
        if col is None:
            continue
        sel = scenes[b]
        xb, vb = x[sel], v[sel]
        xq = xb.detach() if not xb.requires_grad else xb
        phi = col.sdf(xq).to(vb.dtype)  # (Pb,)
        n = col.normal(xq).to(vb.dtype)  # (Pb, 3)
        vn = (vb * n).sum(1)  # (Pb,)
        # the least normal velocity that does not cross the surface within this step
        out = torch.clamp(-push_out * torch.clamp(phi, max=0.0) / dt, max=push_cap)  # (Pb,) >= 0
        floor_vn = out - torch.clamp(phi, min=0.0) / dt
        dvn = torch.clamp(floor_vn - vn, min=0.0)  # (Pb,) >= 0: normal velocity the body adds
        vt = vb - vn[:, None] * n
        if friction > 0:
            vt_norm = vt.norm(dim=1, keepdim=True)
            safe = torch.where(vt_norm > 0, vt_norm, torch.ones_like(vt_norm))
            vt = vt * torch.clamp(1.0 - friction * dvn[:, None] / safe, min=0.0)
            vb_new = torch.where((dvn > 0)[:, None], vt + (vn + dvn)[:, None] * n, vb)
        else:
            vb_new = vb + dvn[:, None] * n
        pieces.append((b, sel, vb_new))
    if len(pieces) == 1 and isinstance(pieces[0][1], slice) and pieces[0][1] == slice(None):
        v_out = pieces[0][2]
    else:
        v_out = v.clone()
        for _, sel, vb_new in pieces:
            v_out[sel] = vb_new
    particle_force = mass[:, None].to(v.dtype) * (v_out - v) / dt  # (P, 3)
    for b, sel, _ in pieces:
        force[b] = particle_force[sel].sum(0)
    return v_out, force, particle_force


def stencil_nodes(st: Stencil) -> Tensor:
    """(27, P) int64 block-grid index of each particle's 27 stencil nodes (offsets (i, j, k), i slowest)."""
    S0, S1 = st.D[1] * st.D[2], st.D[2]
    o = stencil_offsets(st.lin.device, torch.int64)  # (27, 3)
    return st.lin[None, :] + (o[:, 0] * S0 + o[:, 1] * S1 + o[:, 2])[:, None]


def particle_contact_step(
    solver: MLSMPM,
    state: ParticleState,
    st: Stencil,
    gv: Tensor,
    colliders: Sequence[Collider | None],
    hand_velocity: Tensor | None,
    alpha: Tensor | None,
    B: int,
    block: int | None,
) -> ParticleState:
    """G2P (paper eq. 8-11) with the rigid bodies acting on the particles; sets ``solver.last_force`` (B, 3) and the
    (P, 3) particle forces that ``solver.last_particle_force`` returns.

    ``ITERATIONS`` times: gather each particle's velocity (eq. 8) from the grid velocities ``gv`` (N, 3); let
    :func:`collide_particles` give the impulse ``J_p = m_p dv_p`` that keeps it out of the bodies (and moves a particle
    found inside back out by ``PUSH_OUT`` of its depth); scatter the impulses to the grid like momentum (eq. 6):
    ``v_i += sum_p w_ip J_p / m_i``. Then G2P of the corrected grid (eq. 8-11). A particle with ``alpha_p < 1``
    follows the grid only in part (eq. 8), so its impulse is ``alpha_p J_p``: the rigid hand (``alpha = 0``) is not
    held by the object (its impulse could never reach it and would pile up on the grid).

    The impulse acts through the grid, like any external force, so a held particle's ``C`` (eq. 9) and ``F`` (eq. 11)
    see the held velocity field. (Correcting the particle velocities alone leaves the grid below a held particle free:
    its stress then leaks away through ``C``; measured: half the force at 0.03 of the P-wave speed.) One scatter
    shares a particle's impulse with the neighbours of its nodes, so it is repeated on what is left (Jacobi
    iterations); what the last one leaves lets a particle sink a little, corrected at the next steps.
    """
    scenes = scene_slices(state.batch, B, block)
    dt, mu_f = solver.dt, solver.cfg.friction
    cap = PUSH_CAP_CELLS * solver.dx / dt
    gm = solver._last_transfer.node_mass.to(gv.dtype)
    inv_m = torch.where(gm > 0, 1.0 / torch.where(gm > 0, gm, torch.ones_like(gm)), torch.zeros_like(gm))[:, None]
    idx = stencil_nodes(st)  # (27, P)
    w = st.w.to(gv.dtype)[:, :, None]  # (27, P, 1)
    total = None
    for _ in range(ITERATIONS):
        v = (w * gv[idx]).sum(0)  # (P, 3) sum_i w_ip v_i
        if alpha is not None:  # paper eq. 8 (eq:particle_v)
            hv = torch.zeros(3, dtype=v.dtype, device=v.device) if hand_velocity is None else hand_velocity
            v = alpha[:, None] * v + (1.0 - alpha[:, None]) * hv
        _, _, f_p = collide_particles(state.x, v, state.mass, colliders, scenes, dt, mu_f, PUSH_OUT, cap)
        if alpha is not None:  # the grid moves only the alpha share of a particle (eq. 8): the hand is not held
            f_p = alpha[:, None] * f_p
        dp = torch.zeros_like(gv).index_add(0, idx.reshape(-1), (w * (f_p * dt)[None]).reshape(-1, 3))  # (N, 3)
        gv = gv + dp * inv_m
        total = f_p if total is None else total + f_p
    assert total is not None
    force = torch.stack([total[sel].sum(0) for sel in scenes])  # (B, 3)
    solver.last_force = torch.where(
        torch.tensor([c is not None for c in colliders], device=force.device)[:, None], force, torch.zeros_like(force)
    )
    solver._particle_contact_force = total.detach()
    return solver._g2p(state, st, gv, hand_velocity, alpha)
