"""The solver's inputs: its parameters (:class:`MPMConfig`, the CFL time step :func:`cfl_dt`) and the particle
state it advances (:class:`ParticleState`)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from tvrecon.sim.mpm.materials import p_wave_speed
from tvrecon.utils.shape_check import check_shape

__all__ = ["CONTACT_MODES", "MPMConfig", "ParticleState", "cfl_dt"]

#: ``MPMConfig.contact`` values: "grid" (the node collider, the solver's default and the simulator contract) or
#: "particle" (:mod:`tvrecon.sim.mpm.particle_contact`; the default of the press, ``PressConfig.contact``).
CONTACT_MODES = ("grid", "particle")


@dataclass
class MPMConfig:
    """Solver parameters.

    n_grid: cells across the unit domain, ``dx = 1 / n_grid``.
    dt: time step; None -> CFL rule ``cfl_dt(cfg)`` from E, nu, rho, dx.
    E, nu: Young's modulus and Poisson ratio (python floats or 0-dim tensors that may require grad).
    rho: density used by the CFL rule (particle masses live in ``ParticleState``).
    friction: Coulomb coefficient on collider nodes (0 = frictionless slip).
    damping: viscous damping of grid velocity, ``v_i *= exp(-damping dt)``.
    cfl: Courant number of the CFL rule.
    contact: "grid" (default: colliders act on grid nodes, the contract) or "particle" (opt-in here, the default of
        the press, ``PressConfig.contact``: they act on the particles after G2P, contact starting when a particle
        reaches the surface; :mod:`.particle_contact`).
    """

    n_grid: int = 128
    dt: float | None = None
    E: float | Tensor = 3.0
    nu: float | Tensor = 0.25
    rho: float = 1.0
    friction: float = 0.0
    damping: float = 0.0
    cfl: float = 0.3
    contact: str = "grid"


def cfl_dt(cfg: MPMConfig) -> float:
    """CFL time step ``dt = cfl * dx / c`` with the P-wave speed ``c = sqrt((lambda + 2 mu) / rho)``.

    Args:
        cfg: solver config (E, nu may be tensors: their current values are used).

    Returns:
        dt in seconds (python float).
    """
    if cfg.n_grid < 4:
        raise ValueError(f"n_grid must be >= 4, got {cfg.n_grid}")
    if not cfg.rho > 0:
        raise ValueError(f"rho must be > 0, got {cfg.rho}")
    if not 0 < cfg.cfl <= 1:
        raise ValueError(f"cfl must be in (0, 1], got {cfg.cfl}")
    return cfg.cfl * (1.0 / cfg.n_grid) / p_wave_speed(cfg.E, cfg.nu, cfg.rho)


@dataclass
class ParticleState:
    """Particle state of MLS-MPM (P particles).

    x: (P, 3) float positions (domain units, nominally in [0, 1)^3).
    v: (P, 3) velocities.
    C: (P, 3, 3) affine velocity field (APIC / MLS, updated by paper eq. 9).
    F: (P, 3, 3) deformation gradient (paper eq. 1).
    volume: (P,) initial volume V0.
    mass: (P,) mass rho * V0.
    batch: (P,) int64 scene index for batched independent scenes (None = one scene).
    """

    x: Tensor
    v: Tensor
    C: Tensor
    F: Tensor
    volume: Tensor
    mass: Tensor
    batch: Tensor | None = None

    @classmethod
    def create(
        cls,
        x0: Tensor,
        v0: Tensor | None,
        volume: float | Tensor,
        rho: float = 1.0,
        batch: Tensor | None = None,
    ) -> ParticleState:
        """Rest state: F = I, C = 0, mass = rho * volume.

        Args:
            x0: (P, 3) float positions.
            v0: (P, 3) velocities, or None for zeros.
            volume: scalar or (P,) initial particle volume V0.
            rho: density.
            batch: (P,) integer scene index in [0, B) or None.
        """
        if not isinstance(x0, Tensor):
            raise ValueError(f"x0 must be a (P, 3) tensor, got {type(x0).__name__}")
        check_shape(x0, "(P, 3)", "x0")
        if not x0.is_floating_point():
            raise ValueError(f"x0 must be a float tensor, got {x0.dtype}")
        P = x0.shape[0]
        if P == 0:
            raise ValueError("x0 is empty: need at least one particle")
        if not bool(torch.isfinite(x0).all()):
            raise ValueError("x0 contains NaN or inf positions")
        if v0 is None:
            v0 = torch.zeros_like(x0)
        elif not isinstance(v0, Tensor) or v0.shape != x0.shape:
            raise ValueError(f"v0 must be a (P, 3) tensor like x0 {tuple(x0.shape)}, got {tuple(v0.shape)}")
        vol = torch.as_tensor(volume, dtype=x0.dtype, device=x0.device)
        if vol.dim() == 0:
            vol = vol.expand(P).clone()
        if vol.shape != (P,):
            raise ValueError(f"volume must be a scalar or a (P,) tensor with P={P}, got {tuple(vol.shape)}")
        if not bool((vol > 0).all()):
            raise ValueError("volume must be > 0")
        if not rho > 0:
            raise ValueError(f"rho must be > 0, got {rho}")
        if batch is not None:
            if not isinstance(batch, Tensor) or batch.shape != (P,) or batch.is_floating_point():
                raise ValueError(f"batch must be a (P,) integer tensor, got {getattr(batch, 'shape', batch)}")
            batch = batch.to(device=x0.device, dtype=torch.int64)
            if bool((batch < 0).any()):
                raise ValueError("batch indices must be >= 0")
        eye = torch.eye(3, dtype=x0.dtype, device=x0.device).expand(P, 3, 3).clone()
        return cls(
            x=x0,
            v=v0.to(x0.dtype),
            C=torch.zeros(P, 3, 3, dtype=x0.dtype, device=x0.device),
            F=eye,
            volume=vol,
            mass=rho * vol,
            batch=batch,
        )

    @property
    def num_scenes(self) -> int:
        """Number of independent scenes B (1 when batch is None)."""
        return 1 if self.batch is None else int(self.batch.max()) + 1
