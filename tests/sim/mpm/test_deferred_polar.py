"""``MLSMPM.deferred_polar`` (the GPU's default): the polar decomposition's fixed Newton steps with the convergence
test read by the press loop's one host read. The press equals the iterating polar's to float32 round-off; a step
whose fixed steps did not converge is run again with the iterating loop, and a solver used alone reads the test
itself."""

import dataclasses
import warnings

import pytest
import torch
import trimesh

import tvrecon.sim.mpm.solver as solver_mod
from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.mpm.materials import polar_decomposition_fixed
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import MPMConfig, ParticleState


def _press(monkeypatch: pytest.MonkeyPatch, deferred: bool | None) -> list:
    monkeypatch.setattr(MLSMPM, "deferred_polar", deferred)
    sim = EIPSimulator(SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1], [0.04, 0.0, 0.09]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [0.3, 0.0, -1.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sim.press_batch(mesh, pos, dirs)


def _close(a: list, b: list) -> None:
    for ra, rb in zip(a, b):
        assert ra.steps == rb.steps and ra.contact and rb.contact
        assert torch.allclose(ra.image, rb.image, atol=2e-4), (ra.image - rb.image).abs().max()
        assert torch.allclose(ra.force, rb.force, rtol=1e-3, atol=1e-6)


def test_deferred_polar_press_equals_the_iterating_one(monkeypatch):
    _close(_press(monkeypatch, False), _press(monkeypatch, True))


def test_a_step_that_did_not_converge_runs_again(monkeypatch):
    exact = _press(monkeypatch, False)
    redone = []

    def one_step(F, n_iter=1, tol=None):  # noqa: ANN001, ANN202 (too few steps for any deformed particle)
        R, ok = polar_decomposition_fixed(F, 1, tol)
        redone.append(not bool(ok))
        return R, ok

    monkeypatch.setattr(solver_mod, "polar_decomposition_fixed", one_step)
    _close(exact, _press(monkeypatch, True))
    assert sum(redone) > 10  # most pressed steps were run again with the iterating loop


def test_a_solver_alone_reads_the_test_itself(monkeypatch):
    g = torch.Generator().manual_seed(0)
    x = 0.4 + 0.2 * torch.rand(200, 3, generator=g)
    state = ParticleState.create(x, torch.zeros(200, 3), volume=torch.full((200,), 1e-5), rho=1.0)
    F = torch.diag(torch.tensor([0.9, 1.0, 1.1])) + 0.05 * torch.randn(200, 3, 3, generator=g)
    state = dataclasses.replace(state, F=F)

    def step(deferred: bool | None) -> ParticleState:
        monkeypatch.setattr(MLSMPM, "deferred_polar", deferred)
        solver = MLSMPM(MPMConfig(n_grid=16), compile=False)
        out = solver.step(state)
        assert solver.pending_polar_ok is None  # no caller's read to leave it to
        return out

    exact = step(False)
    assert torch.allclose(step(True).F, exact.F, atol=1e-6)
    monkeypatch.setattr(solver_mod, "polar_decomposition_fixed", lambda F: polar_decomposition_fixed(F, 1))
    assert torch.equal(step(True).F, exact.F)  # not converged in one step: the iterating loop's R
