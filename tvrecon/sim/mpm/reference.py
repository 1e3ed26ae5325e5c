"""Naive MLS-MPM: a straightforward torch port of the simulator contract (the mpm88 family), the solver's reference.

Read it next to :class:`tvrecon.sim.mpm.solver.MLSMPM`: the same P2G (paper eq. 5-6), grid velocity and colliders (eq.
7) and G2P (eq. 8-11), written as directly as possible (``docs/simulator-contract.md`` states the contract). The tests
compare the two (``tests/sim/test_mpm.py``) and ``benchmarks/bench_sim.py`` times them.

Dense ``n_grid^3`` grid, a python loop over the 27 stencil offsets with one ``index_add_`` per quantity,
``torch.linalg.svd`` for the polar decomposition and ``P(F) = 2 mu (F - R) + lam (J - 1) J F^-T`` with
``torch.linalg.inv``. Deliberately independent of ``tvrecon.sim.mpm`` (only the colliders' sdf/normal and the
textbook Lamé formulas of ``tvrecon.sim.mpm.materials.lame_parameters`` are shared), so that agreement between the two
is a real check.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor

from tvrecon.sim.mpm.materials import lame_parameters


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
        friction: Coulomb coefficient on collider nodes.
    """

    def __init__(self, n_grid: int, dt: float, E: float, nu: float, friction: float = 0.0) -> None:
        self.n = n_grid
        self.dx = 1.0 / n_grid
        self.dt = dt
        self.mu, self.lam = lame_parameters(E, nu)
        self.friction = friction
        self.last_force = torch.zeros(3)

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
        """One step; x, v: (P, 3); C, F: (P, 3, 3); vol, mass: (P,). Returns new (x, v, C, F)."""
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
        if collider is not None:
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
