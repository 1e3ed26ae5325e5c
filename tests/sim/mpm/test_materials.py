"""Fixed-corotated material and polar decomposition against independent references (SVD, autograd)."""

import pytest
import torch

from tvrecon.sim.mpm import materials
from tvrecon.sim.mpm.materials import (
    det3,
    fixed_corotated_energy,
    fixed_corotated_kirchhoff,
    fixed_corotated_stress,
    lame_parameters,
    p_wave_speed,
    polar_decomposition,
    polar_decomposition_fixed,
)


def _random_F(n: int, scale: float, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(1)
    return torch.eye(3, dtype=dtype) + scale * torch.randn(n, 3, 3, generator=g, dtype=dtype)


@pytest.mark.parametrize("dtype,atol", [(torch.float64, 1e-10), (torch.float32, 2e-5)])
def test_polar_matches_svd(dtype, atol):
    F = _random_F(500, 0.3, dtype)
    U, _, Vh = torch.linalg.svd(F.double())
    R_ref = (U @ Vh).to(dtype)
    R = polar_decomposition(F)
    assert torch.allclose(R, R_ref, atol=atol)
    eye = torch.eye(3, dtype=dtype)
    assert torch.allclose(R.mT @ R, eye.expand_as(R), atol=atol)


def test_polar_large_deformation():
    F = torch.diag_embed(torch.tensor([[0.2, 1.0, 4.0], [3.0, 0.5, 1.5]], dtype=torch.float64))
    rot = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.7, 0.2], [0.7, 0.0, -0.4], [-0.2, 0.4, 0.0]]).double())
    R = polar_decomposition(rot @ F)
    assert torch.allclose(R, rot.expand(2, 3, 3), atol=1e-10)


@pytest.mark.parametrize("dtype,atol,steps", [(torch.float64, 1e-10, 6), (torch.float32, 2e-5, 4)])
def test_fixed_step_polar_matches_the_iterating_one(dtype, atol, steps):
    F = _random_F(500, 0.1, dtype)  # |sigma - 1| up to ~0.3: a press's range (float64's stop needs a 5th step)
    R, ok = polar_decomposition_fixed(F, n_iter=steps)
    assert ok.dtype == torch.bool and ok.dim() == 0 and bool(ok)
    assert torch.allclose(R, polar_decomposition(F), atol=atol)


def test_fixed_step_polar_converges_on_a_paper_press_compression(monkeypatch):
    """The authors' pad pressed 12% of the object deep compresses particles to singular values ~0.2 (measured 0.216 to
    1.57 over a press of the paper scene): the default 4 steps (2 scaled, 2 plain) converge there, float32 as pressed,
    and give the SVD's rotation, so the GPU's deferred polar is not run again with the iterating loop."""
    g = torch.Generator().manual_seed(3)
    n = 2000
    Q = torch.linalg.qr(torch.randn(2 * n, 3, 3, generator=g, dtype=torch.float64))[0]
    sigma = 0.2 + 1.4 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    F = Q[:n] @ torch.diag_embed(sigma) @ Q[n:]
    U, _, Vh = torch.linalg.svd(F)
    R, ok = polar_decomposition_fixed(F.float())
    assert bool(ok)
    assert torch.allclose(R.double(), U @ Vh, atol=2e-5)
    # the plain step alone does not get there in 4 steps: the two scaled ones are what converges it
    squeezed = torch.diag(torch.tensor([0.2, 1.0, 1.0]))[None]
    assert bool(polar_decomposition_fixed(squeezed)[1])
    monkeypatch.setattr(materials, "POLAR_SCALED_ITERS", 0)
    assert not bool(polar_decomposition_fixed(squeezed)[1])


def test_fixed_step_polar_reports_what_it_could_not_do():
    big = torch.diag_embed(torch.tensor([[0.05, 1.0, 20.0]], dtype=torch.float64))  # needs more than 4 steps
    assert not bool(polar_decomposition_fixed(big)[1])
    assert torch.allclose(polar_decomposition_fixed(big, n_iter=12)[0], torch.eye(3, dtype=torch.float64)[None])
    bad = torch.eye(3)[None].repeat(3, 1, 1)
    bad[1, 0, 0] = float("nan")
    R, ok = polar_decomposition_fixed(bad)
    assert not bool(ok) and torch.equal(R[0], torch.eye(3))  # the others are still right
    assert not bool(polar_decomposition_fixed(torch.zeros(1, 3, 3))[1])  # singular


def test_det3_matches_linalg():
    F = _random_F(100, 0.5)
    assert torch.allclose(det3(F), torch.linalg.det(F), atol=1e-12)


def test_stress_is_autograd_of_energy():
    """P(F) equals dPsi/dF with Psi computed independently from singular values (paper eq. 3-4)."""
    mu, lam = lame_parameters(3.0, 0.3)
    F = _random_F(64, 0.2).requires_grad_(True)
    sigma = torch.linalg.svdvals(F)
    psi = mu * (sigma - 1).square().sum(-1) + 0.5 * lam * (torch.linalg.det(F) - 1).square()
    (grad,) = torch.autograd.grad(psi.sum(), F)
    P = fixed_corotated_stress(F.detach(), mu, lam)
    assert torch.allclose(P, grad, atol=1e-8)
    energy = fixed_corotated_energy(F.detach(), mu, lam)
    assert torch.allclose(energy, psi.detach(), atol=1e-10)


def test_rotation_has_zero_stress_and_kirchhoff_is_PFt():
    mu, lam = lame_parameters(3.0, 0.25)
    skew = torch.randn(20, 3, 3, dtype=torch.float64)
    rot = torch.linalg.matrix_exp(skew - skew.mT)
    assert fixed_corotated_stress(rot, mu, lam).abs().max() < 1e-10
    F = _random_F(20, 0.2)
    P = fixed_corotated_stress(F, mu, lam)
    assert torch.allclose(fixed_corotated_kirchhoff(F, mu, lam), P @ F.mT, atol=1e-10)


def test_gradient_flows_to_E_and_nu():
    E = torch.tensor(3.0, dtype=torch.float64, requires_grad=True)
    nu = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
    mu, lam = lame_parameters(E, nu)
    F = _random_F(10, 0.1)
    fixed_corotated_stress(F, mu, lam).square().sum().backward()
    assert E.grad is not None and E.grad.abs() > 0
    assert nu.grad is not None and nu.grad.abs() > 0


def test_p_wave_speed_is_the_textbook_formula():
    """c = sqrt((lambda + 2 mu) / rho) = sqrt(E (1 - nu) / ((1 + nu)(1 - 2 nu) rho)); tensors give their value."""
    E, nu, rho = 3.0, 0.25, 2.0
    assert p_wave_speed(E, nu, rho) == pytest.approx((E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho)) ** 0.5)
    t = p_wave_speed(torch.tensor(E, requires_grad=True), torch.tensor(nu), rho)
    assert isinstance(t, float) and t == pytest.approx(p_wave_speed(E, nu, rho), rel=1e-6)
    with pytest.raises(ValueError, match="rho"):
        p_wave_speed(E, nu, 0.0)


def test_bad_inputs():
    with pytest.raises(ValueError, match="Poisson ratio"):
        lame_parameters(3.0, 0.5)
    with pytest.raises(ValueError, match="Young's modulus"):
        lame_parameters(-1.0, 0.2)
    with pytest.raises(ValueError, match=r"F must have shape \(P, 3, 3\), got \(3, 3\)"):
        polar_decomposition(torch.eye(3))
    with pytest.raises(ValueError, match=r"E must have shape \(\), got \(2,\)"):
        lame_parameters(torch.ones(2), 0.2)
