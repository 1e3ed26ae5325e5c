"""Fixed-corotated elasticity (paper eq. 2-4) and the 3x3 polar decomposition it needs.

All functions are batched over a leading particle dimension P, work in float32 or float64 on any device, and are
differentiable by autograd (E and nu may be python floats or 0-dim tensors that require grad).

The polar decomposition uses the scaled Newton iteration of Higham (1986), ``X <- (g X + X^-T / g) / 2`` with the
analytic 3x3 inverse (cofactors): no SVD, and unlike the SVD its autograd derivative is well defined at repeated
singular values (e.g. the rest state F = I).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from tvrecon.sim.mpm.small_matmul import matmul3
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "lame_parameters",
    "p_wave_speed",
    "det3",
    "cofactor3",
    "polar_decomposition",
    "polar_decomposition_fixed",
    "POLAR_FIXED_ITERS",
    "POLAR_SCALED_ITERS",
    "fixed_corotated_energy",
    "fixed_corotated_stress",
    "fixed_corotated_kirchhoff",
]


def lame_parameters(E: float | Tensor, nu: float | Tensor) -> tuple[float | Tensor, float | Tensor]:
    """Lamé parameters ``mu = E / (2 (1 + nu))``, ``lambda = E nu / ((1 + nu)(1 - 2 nu))`` (paper, after eq. 3).

    Args:
        E: Young's modulus, > 0 (python float or 0-dim tensor, may require grad).
        nu: Poisson ratio in [0, 0.5) (python float or 0-dim tensor, may require grad).

    Returns:
        (mu, lam) of the same kind as the inputs (floats or 0-dim tensors).
    """
    for value, name in ((E, "E"), (nu, "nu")):
        if isinstance(value, Tensor):
            check_shape(value, "()", name)
    e_val = float(E.detach()) if isinstance(E, Tensor) else float(E)
    nu_val = float(nu.detach()) if isinstance(nu, Tensor) else float(nu)
    if not e_val > 0:
        raise ValueError(f"Young's modulus E must be > 0, got {e_val}")
    if not 0.0 <= nu_val < 0.5:
        raise ValueError(f"Poisson ratio nu must be in [0, 0.5), got {nu_val}")
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def p_wave_speed(E: float | Tensor, nu: float | Tensor, rho: float) -> float:
    """Elastic P-wave speed ``c = sqrt((lambda + 2 mu) / rho)``, the speed that bounds the CFL step and the press.

    Args:
        E: Young's modulus, > 0 (python float or 0-dim tensor: its current value is used).
        nu: Poisson ratio in [0, 0.5) (python float or 0-dim tensor).
        rho: density, > 0.

    Returns:
        c in domain units per second (python float).
    """
    if not float(rho) > 0:
        raise ValueError(f"density rho must be > 0, got {rho}")
    mu, lam = lame_parameters(E, nu)
    return math.sqrt((float(lam) + 2.0 * float(mu)) / float(rho))


def _check_mats(F: Tensor, name: str = "F") -> None:
    if not isinstance(F, Tensor):
        raise ValueError(f"{name} must be a (P, 3, 3) tensor, got {type(F).__name__}")
    check_shape(F, "(P, 3, 3)", name)


# cof(F)_k = F[a_k] F[b_k] - F[c_k] F[d_k] over the row-major entries f00..f22 (rows: r1 x r2, r2 x r0, r0 x r1)
_COF_IDX = (
    (4, 5, 3, 7, 8, 6, 1, 2, 0)
    + (8, 6, 7, 2, 0, 1, 5, 3, 4)
    + (5, 3, 4, 8, 6, 7, 2, 0, 1)
    + (7, 8, 6, 1, 2, 0, 4, 5, 3)
)
_COF_CACHE: dict[torch.device, Tensor] = {}


def cofactor3(F: Tensor) -> Tensor:
    """Cofactor matrix of a batch of 3x3 matrices, ``cof(F) = det(F) F^-T``.

    Args:
        F: (P, 3, 3) float tensor.

    Returns:
        (P, 3, 3) cofactor matrices (rows: r1 x r2, r2 x r0, r0 x r1 for the rows r0, r1, r2 of F).
    """
    idx = _COF_CACHE.get(F.device)
    if idx is None:
        idx = _COF_CACHE.setdefault(F.device, torch.tensor(_COF_IDX, device=F.device))
    g = F.reshape(-1, 9).index_select(1, idx).view(-1, 4, 9)  # one gather of the four factor tables
    return (g[:, 0] * g[:, 1] - g[:, 2] * g[:, 3]).view(-1, 3, 3)


def det3(F: Tensor) -> Tensor:
    """Analytic determinant of a batch of 3x3 matrices (``J_p = det(F_p)``: paper eq. 2, no LaTeX label).

    Args:
        F: (P, 3, 3) float tensor.

    Returns:
        (P,) determinants.
    """
    return (F[:, 0] * torch.linalg.cross(F[:, 1], F[:, 2], dim=1)).sum(-1)


def _newton_start(F: Tensor, tol: float | None) -> tuple[Tensor, Tensor, float]:
    """The scaled Newton iteration's start: F's (9, P) entries as contiguous rows (so every op of a step is a flat
    vector op), the cofactor index table of F's device and the step-size stop ``sqrt(2 tol)`` (tol: default 4 eps)."""
    _check_mats(F)
    if tol is None:
        tol = 4.0 * torch.finfo(F.dtype).eps
    idx = _COF_CACHE.get(F.device)
    if idx is None:
        idx = _COF_CACHE.setdefault(F.device, torch.tensor(_COF_IDX, device=F.device))
    return F.reshape(F.shape[0], 9).T.contiguous(), idx, (2.0 * tol) ** 0.5


def _newton_step(X: Tensor, idx: Tensor) -> tuple[Tensor, Tensor]:
    """One scaled Newton step ``X <- (g X + X^-T / g) / 2`` of (9, P) rows; returns the new rows and each particle's
    (P,) largest entry change."""
    g4 = X.index_select(0, idx)  # (36, P): the four factor tables of the cofactors
    cof = g4[0:9] * g4[9:18] - g4[18:27] * g4[27:36]  # (9, P) = det(X) X^-T
    det = (X[0:3] * cof[0:3]).sum(0)  # (P,)
    inv_t = cof / det  # X^-T
    # Frobenius scaling g = (|X^-1|_F / |X|_F)^(1/2), ~1 near convergence, keeps Newton quadratically convergent
    gs = (inv_t.square().sum(0) / X.square().sum(0)).pow(0.25)
    X_new = 0.5 * (gs * X + inv_t / gs)
    return X_new, (X_new - X).detach().abs().amax(0)


def polar_decomposition(F: Tensor, max_iter: int = 20, tol: float | None = None) -> Tensor:
    """Orthogonal factor R of the polar decomposition ``F = R S`` (S symmetric positive semi-definite).

    Scaled Newton iteration ``X <- (g X + X^-T / g) / 2`` with Frobenius-norm scaling ``g`` (Higham 1986) and the
    analytic cofactor inverse; each particle iterates until it has converged. Convergence is quadratic
    (error_k+1 ~ error_k^2 / 2, and the step size estimates the error), so a particle stops once its largest entry
    changed by less than ``sqrt(2 tol)``: its iterate is then within ~``tol`` of R. Matches ``U V^T`` from
    ``torch.linalg.svd`` (also a reflection when ``det F < 0``, exactly like the SVD formula) to round-off;
    1 iteration at F = R, 3 for |sigma - 1| ~ 0.1.

    Args:
        F: (P, 3, 3) float32/float64 tensor, non-singular.
        max_iter: iteration cap.
        tol: target accuracy; default 4 eps of the dtype.

    Returns:
        (P, 3, 3) orthogonal matrices R, same dtype as F.
    """
    X, idx, stop = _newton_start(F, tol)
    P = F.shape[0]
    active: Tensor | None = None  # indices of the particles still iterating (None = all)
    for _ in range(max_iter):
        Xa = X if active is None else X.index_select(1, active)
        X_new, delta = _newton_step(Xa, idx)
        X = X_new if active is None else X.index_copy(1, active, X_new)
        busy = delta >= stop
        # one host read: the non-finite count (NaN and inf are never < inf) and the count still iterating
        n_bad, n_busy = torch.stack([(~(delta < math.inf)).sum(), busy.sum()]).tolist()
        if n_bad:
            raise FloatingPointError(
                "polar decomposition of a singular or non-finite deformation gradient F: the simulation became "
                "unstable; reduce dt / hand speed, increase n_grid"
            )
        if n_busy == 0:
            break
        # keep iterating only the particles that have not converged, on the CPU (a GPU iterates them all: the
        # compaction would cost a host sync, the extra particles almost nothing)
        if n_busy < 0.5 * busy.numel() and X.device.type == "cpu":
            sel = busy.nonzero()[:, 0]
            active = sel if active is None else active[sel]
    return X.T.reshape(P, 3, 3)


#: Newton steps of :func:`polar_decomposition_fixed` and of the compiled kernel's ``polar_fixed``: the eager loop needs
#: 1 at F = R and ~3 for |sigma - 1| ~ 0.1; a particle not converged after them makes the caller iterate again
POLAR_FIXED_ITERS = 4


#: of :func:`polar_decomposition_fixed`'s steps, the first ones scaled: the press of the authors' pad compresses
#: particles to sigma ~0.2, which the plain step alone does not bring within the stop in 4 steps
POLAR_SCALED_ITERS = 2


def _newton_step_lean(X: Tensor, idx: Tensor, scaled: bool) -> Tensor:
    """One Newton step of (9, P) rows for :func:`polar_decomposition_fixed`, in few launches and without the step
    size: ``X <- (g X + X^-T / g) / 2`` with the Frobenius scaling g of :func:`_newton_step` (13 aten ops) or the
    plain ``X <- (X + X^-T) / 2`` (g = 1: 7 ops), as fast near a rotation, where the scaling is ~1."""
    g4 = X.index_select(0, idx)  # (36, P): the four factor tables of the cofactors
    cof = torch.addcmul(g4[0:9] * g4[9:18], g4[18:27], g4[27:36], value=-1.0)  # (9, P) = det(X) X^-T
    det = (X[0:3] * cof[0:3]).sum(0)  # (P,)
    if not scaled:
        return torch.addcdiv(X, cof, det).mul_(0.5)
    inv_t = cof / det  # X^-T
    gs = (torch.linalg.vector_norm(inv_t, dim=0) / torch.linalg.vector_norm(X, dim=0)).sqrt()
    return torch.addcdiv(gs * X, inv_t, gs).mul_(0.5)


def polar_decomposition_fixed(
    F: Tensor, n_iter: int = POLAR_FIXED_ITERS, tol: float | None = None
) -> tuple[Tensor, Tensor]:
    """:func:`polar_decomposition` without a host read: ``n_iter`` Newton steps of every particle (the first
    :data:`POLAR_SCALED_ITERS` scaled, the rest plain) and the iterating loop's stop test on the last one.

    The loop reads, every iteration, whether to go on (a host sync each, ~1.4 a press step); this one returns that
    answer as a tensor for the caller's own read, so a GPU streams the step. It is also lean in launches (~45 aten ops
    for 4 steps, against ~95 with the loop's step-size test and a per-particle freeze each step;
    ``tests/sim/mpm/test_step_counts.py``): a converged particle stays at its fixed point, so freezing it changes
    nothing, and once the scaled steps have brought F's singular values near 1 the scaling is ~1 and the plain step
    converges as fast (quadratically). Where ``converged`` is False (the last step was not below the stop: F far from a
    rotation, singular or not finite) the caller runs :func:`polar_decomposition`, which iterates further or raises.

    Args:
        F: (P, 3, 3) float32/float64, non-singular. n_iter: Newton steps (>= 1). tol: as :func:`polar_decomposition`.

    Returns:
        R: (P, 3, 3) and converged: 0-dim bool, every particle's last step below the stop (a NaN step never is).
    """
    if n_iter < 1:
        raise ValueError(f"n_iter must be >= 1, got {n_iter}")
    X, idx, stop = _newton_start(F, tol)
    P = F.shape[0]
    X_prev = X
    for i in range(n_iter):
        X_prev, X = X, _newton_step_lean(X, idx, i < POLAR_SCALED_ITERS)
    converged = ((X - X_prev).detach().abs_().amax(0) < stop).all()
    return X.T.reshape(P, 3, 3), converged


def fixed_corotated_energy(F: Tensor, mu: float | Tensor, lam: float | Tensor) -> Tensor:
    """Fixed-corotated energy density ``mu sum_i (sigma_i - 1)^2 + lam / 2 (J - 1)^2`` (paper eq. 3, eq:phi).

    Uses ``sum_i (sigma_i - 1)^2 = |F - R|_F^2``.

    Args:
        F: (P, 3, 3) deformation gradients.
        mu, lam: Lamé parameters (floats or 0-dim tensors).

    Returns:
        (P,) energy density per unit rest volume.
    """
    _check_mats(F)
    R = polar_decomposition(F)
    J = det3(F)
    return mu * (F - R).square().sum((1, 2)) + 0.5 * lam * (J - 1.0).square()


def fixed_corotated_stress(F: Tensor, mu: float | Tensor, lam: float | Tensor, R: Tensor | None = None) -> Tensor:
    """First Piola-Kirchhoff stress ``P = 2 mu (F - R) + lam (J - 1) J F^-T`` (paper eq. 4, eq:PK).

    Args:
        F: (P, 3, 3) deformation gradients (non-singular).
        mu, lam: Lamé parameters (floats or 0-dim tensors).
        R: optional (P, 3, 3) precomputed polar rotation of F.

    Returns:
        (P, 3, 3) stress P(F); zero when F is a rotation.
    """
    _check_mats(F)
    if R is None:
        R = polar_decomposition(F)
    cof = cofactor3(F)  # = J F^-T
    J = (F[:, 0] * cof[:, 0]).sum(-1)[:, None, None]
    return 2.0 * mu * (F - R) + lam * (J - 1.0) * cof


def fixed_corotated_kirchhoff(F: Tensor, mu: float | Tensor, lam: float | Tensor, R: Tensor | None = None) -> Tensor:
    """Kirchhoff stress ``P(F) F^T = 2 mu (F - R) F^T + lam (J - 1) J I`` used by the MLS-MPM scatter (paper eq. 6).

    Algebraically identical to ``fixed_corotated_stress(F) @ F.mT`` but needs no inverse.

    Args:
        F: (P, 3, 3) deformation gradients.
        mu, lam: Lamé parameters (floats or 0-dim tensors).
        R: optional (P, 3, 3) precomputed polar rotation of F.

    Returns:
        (P, 3, 3) Kirchhoff stress.
    """
    _check_mats(F)
    if R is None:
        R = polar_decomposition(F)
    J = det3(F)
    eye = torch.eye(3, dtype=F.dtype, device=F.device)
    return 2.0 * mu * matmul3(F - R, F.transpose(1, 2)) + (lam * (J - 1.0) * J)[:, None, None] * eye
