"""Naive MLS-MPM: a straightforward torch port of the simulator contract (the mpm88 family), the solver's reference.

Read it next to :class:`tvrecon.sim.mpm.solver.MLSMPM`: the same P2G (paper eq. 5-6), grid velocity and colliders (eq.
7) and G2P (eq. 8-11), written as directly as possible (``docs/reference/simulator-contract.md`` states the
contract). The tests compare the two (``tests/sim/mpm/test_mpm.py``,
``tests/sim/mpm/test_reference_particle_contact.py``) and ``benchmarks/speed/bench_sim.py`` times them.

Dense ``n_grid^3`` grid, a python loop over the 27 stencil offsets with one ``index_add_`` per quantity,
``torch.linalg.svd`` for the polar decomposition and ``P(F) = 2 mu (F - R) + lam (J - 1) J F^-T`` with
``torch.linalg.inv``. Both contacts of the solver: ``contact="grid"`` (the contract: the collider acts on grid nodes
inside the body) and ``contact="particle"`` (the press's default, :mod:`tvrecon.sim.mpm.particle_contact`: particles
within a cell of the body get a speculative / push-out impulse, scattered to the grid like momentum in a few Jacobi
passes before G2P; :meth:`ReferenceMPM._particle_contact`). Deliberately independent of ``tvrecon.sim.mpm`` (only the
colliders' sdf/normal, the textbook Lamé formulas of ``tvrecon.sim.mpm.materials.lame_parameters`` and the particle
contact's three constants ``PUSH_OUT``, ``PUSH_CAP_CELLS``, ``ITERATIONS`` are shared), so that agreement between the
two is a real check.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor

from tvrecon.sim.mpm.materials import lame_parameters
from tvrecon.sim.mpm.particle_contact import ITERATIONS, PUSH_CAP_CELLS, PUSH_OUT


def _stencil(base: Tensor, fx: Tensor, w: list[Tensor], n: int, dx: float) -> Iterator[tuple[Tensor, Tensor, Tensor]]:
    """The 27 nodes around every particle, one offset (i, j, k) at a time.

    Yields (node index (P,) in the dense ``n^3`` grid, B-spline weight w_ip (P,), x_i - x_p (P, 3)).
    """
    for i in range(3):
        for j in range(3):
            for k in range(3):
                off = torch.tensor([i, j, k], dtype=fx.dtype)
                dpos = (off - fx) * dx
                weight = w[i][:, 0] * w[j][:, 1] * w[k][:, 2]
                idx = base + torch.tensor([i, j, k])
                lin = (idx[:, 0] * n + idx[:, 1]) * n + idx[:, 2]
                yield lin, weight, dpos


class ReferenceMPM:
    """Dense-grid MLS-MPM, one scene.

    Args:
        n_grid: cells across the unit domain.
        dt: time step.
        E, nu: Young's modulus and Poisson ratio.
        friction: Coulomb coefficient of the contact (0 = frictionless slip).
        contact: "grid" (the collider acts on grid nodes, the contract) or "particle" (on the particles near the body,
            through the grid), as ``MPMConfig.contact``.

    After each ``step``: ``last_force`` is the (3,) force the collider exerted on the particles; with
    ``contact="particle"``, ``last_particle_force`` is the (P, 3) force on each particle (what
    ``MLSMPM.last_particle_force`` returns in that mode; None with the grid contact).
    """

    def __init__(
        self, n_grid: int, dt: float, E: float, nu: float, friction: float = 0.0, contact: str = "grid"
    ) -> None:
        if contact not in ("grid", "particle"):
            raise ValueError(f"contact must be 'grid' or 'particle', got {contact!r}")
        self.n = n_grid
        self.dx = 1.0 / n_grid
        self.dt = dt
        self.mu, self.lam = lame_parameters(E, nu)
        self.friction = friction
        self.contact = contact
        self.last_force = torch.zeros(3)
        self.last_particle_force: Tensor | None = None

    @torch.no_grad()
    def step(
        self,
        x: Tensor,
        v: Tensor,
        C: Tensor,
        F: Tensor,
        vol: Tensor,
        mass: Tensor,
        collider=None,
        hand_velocity: Tensor | None = None,
        alpha: Tensor | None = None,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """One step; x, v: (P, 3); C, F: (P, 3, 3); vol, mass: (P,); hand_velocity: (3,) or (P, 3) (None = zero);
        alpha: (P,) (None = all ones). Returns new (x, v, C, F)."""
        n, dx, dt = self.n, self.dx, self.dt
        inv_dx = 1.0 / dx
        base = (x * inv_dx - 0.5).floor().long()  # (P, 3)
        fx = x * inv_dx - base.to(x.dtype)
        w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1) ** 2, 0.5 * (fx - 0.5) ** 2]
        U, _, Vh = torch.linalg.svd(F)
        R = U @ Vh
        J = torch.linalg.det(F)
        P_stress = 2 * self.mu * (F - R) + (self.lam * (J - 1) * J)[:, None, None] * torch.linalg.inv(F).transpose(1, 2)
        stress = -(dt * vol * 4 * inv_dx * inv_dx)[:, None, None] * (P_stress @ F.transpose(1, 2))
        affine = stress + mass[:, None, None] * C
        grid_m = torch.zeros(n * n * n, dtype=x.dtype)
        grid_mv = torch.zeros(n * n * n, 3, dtype=x.dtype)
        for lin, weight, dpos in _stencil(base, fx, w, n, dx):  # P2G (eq. 5-6)
            grid_m.index_add_(0, lin, weight * mass)
            mom = mass[:, None] * v + (affine @ dpos[:, :, None])[:, :, 0]
            grid_mv.index_add_(0, lin, weight[:, None] * mom)
        active = grid_m > 0
        grid_v = torch.zeros_like(grid_mv)
        grid_v[active] = grid_mv[active] / grid_m[active][:, None]
        self.last_force = torch.zeros(3, dtype=x.dtype)
        self.last_particle_force = None
        if collider is not None and self.contact == "particle":
            stencil = [(lin, weight) for lin, weight, _ in _stencil(base, fx, w, n, dx)]
            grid_v = self._particle_contact(x, mass, stencil, grid_m, grid_v, collider, hand_velocity, alpha)
        elif collider is not None:
            ids = active.nonzero()[:, 0]
            pos = torch.stack([ids // (n * n), (ids // n) % n, ids % n], 1).to(x.dtype) * dx
            vi = grid_v[ids]
            sdf = collider.sdf(pos)
            nrm = collider.normal(pos)
            vn = (vi * nrm).sum(1, keepdim=True)
            hit = (sdf[:, None] < 0) & (vn < 0)
            vt = vi - vn * nrm
            if self.friction > 0:
                vtn = vt.norm(dim=1, keepdim=True).clamp_min(1e-30)
                vt = vt * torch.clamp(1 + self.friction * vn / vtn, min=0)
            new = torch.where(hit, vt, vi)
            self.last_force = (grid_m[ids][:, None] * (new - vi)).sum(0) / dt
            grid_v[ids] = new
        new_v = torch.zeros_like(v)
        new_C = torch.zeros_like(C)
        for lin, weight, dpos in _stencil(base, fx, w, n, dx):  # G2P (eq. 8-9)
            gv = grid_v[lin]
            new_v += weight[:, None] * gv
            new_C += 4 * inv_dx * inv_dx * weight[:, None, None] * gv[:, :, None] * dpos[:, None, :]
        if alpha is not None:
            hv = torch.zeros(3, dtype=x.dtype) if hand_velocity is None else hand_velocity
            new_v = alpha[:, None] * new_v + (1 - alpha[:, None]) * hv
        x = x + dt * new_v
        F = (torch.eye(3, dtype=x.dtype) + dt * new_C) @ F
        return x, new_v, new_C, F

    def _particle_contact(
        self,
        x: Tensor,
        mass: Tensor,
        stencil: list[tuple[Tensor, Tensor]],
        grid_m: Tensor,
        grid_v: Tensor,
        collider,
        hand_velocity: Tensor | None,
        alpha: Tensor | None,
    ) -> Tensor:
        """The particle contact on the dense grid velocities, before G2P; sets ``last_force``, ``last_particle_force``.

        Every particle is visited; those within one cell of the body (``phi_p < dx`` at the step's positions ``x``)
        receive an impulse. ``ITERATIONS`` times: gather each particle's velocity from the grid (paper eq. 8, with the
        hand's share ``1 - alpha_p``); let it approach the body by at most ``phi_p`` this step, or leave it by
        ``PUSH_OUT`` of its depth (at most ``PUSH_CAP_CELLS`` cells) when it is inside; take the Coulomb friction
        ``friction * dv_n`` off its tangential velocity; scatter ``alpha_p`` times its impulse ``J_p = m_p (v'_p -
        v_p)`` to the grid like momentum (eq. 6): ``v_i += w_ip alpha_p J_p / m_i`` (all particles from the same grid,
        a Jacobi pass).

        Args:
            x: (P, 3) positions. mass: (P,) masses. stencil: the 27 (node index (P,), weight w_ip (P,)) pairs.
            grid_m: (n^3,) node masses. grid_v: (n^3, 3) node velocities (eq. 7), corrected in place.
            collider: the body (its ``sdf`` (P,) and ``normal`` (P, 3) at ``x``).
            hand_velocity: (3,) or (P, 3) or None. alpha: (P,) or None.
        Returns:
            the corrected (n^3, 3) grid velocities.
        """
        dx, dt, mu_f = self.dx, self.dt, self.friction
        P = x.shape[0]
        phi = collider.sdf(x).to(x.dtype)  # (P,)
        nrm = collider.normal(x).to(x.dtype)  # (P, 3) unit outward normal
        near = phi < dx  # (P,) the particles the body can reach this step
        # the least normal velocity: land on the surface from outside, come out by PUSH_OUT of the depth from inside
        cap = PUSH_CAP_CELLS * dx / dt
        vn_least = torch.where(phi >= 0, -phi / dt, torch.clamp(-PUSH_OUT * phi / dt, max=cap))  # (P,)
        a = torch.ones(P, dtype=x.dtype) if alpha is None else alpha
        hv = torch.zeros(3, dtype=x.dtype) if hand_velocity is None else hand_velocity
        # w_ip dt / m_i per offset (0 on a node without mass, which then has w_ip = 0 too)
        shares = []
        for lin, weight in stencil:
            m_i = grid_m[lin]
            shares.append(torch.where(m_i > 0, weight * dt / torch.where(m_i > 0, m_i, torch.ones_like(m_i)), 0.0))
        total = torch.zeros(P, 3, dtype=x.dtype)
        for _ in range(ITERATIONS):
            vp = torch.zeros(P, 3, dtype=x.dtype)
            for lin, weight in stencil:  # gather (eq. 8)
                vp += weight[:, None] * grid_v[lin]
            if alpha is not None:
                vp = alpha[:, None] * vp + (1 - alpha[:, None]) * hv
            vn = (vp * nrm).sum(1)  # (P,)
            vn_new = torch.maximum(vn, vn_least)
            dvn = vn_new - vn  # (P,) >= 0
            vt = vp - vn[:, None] * nrm
            scale = torch.ones(P, dtype=x.dtype)
            if mu_f > 0:  # Coulomb: the tangential speed loses friction * dv_n, down to 0
                vt_len = vt.norm(dim=1)
                slow = torch.clamp(1 - mu_f * dvn / vt_len.clamp_min(torch.finfo(x.dtype).tiny), min=0)
                scale = torch.where(vt_len > 0, slow, scale)
            v_new = torch.where((dvn > 0)[:, None], scale[:, None] * vt + vn_new[:, None] * nrm, vp)
            f = torch.where(near[:, None], (a * mass / dt)[:, None] * (v_new - vp), 0.0)  # (P, 3) alpha_p J_p / dt
            for (lin, _), share in zip(stencil, shares):  # scatter like momentum (eq. 6)
                grid_v.index_add_(0, lin, share[:, None] * f)
            total += f
        self.last_force = total.sum(0)
        self.last_particle_force = total
        return grid_v
