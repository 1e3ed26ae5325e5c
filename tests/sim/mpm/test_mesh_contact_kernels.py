"""The compiled particle contact with stacked mesh colliders: its prefilter (``near_blocks``, kernel ``"near"``) and its
lookup and set-up (``mesh_contact``, kernel ``"mesh_contact"``) are the eager search's arithmetic as pure functions
(equal bit for bit when run uncompiled), and a compiled batched mesh press runs them every step and reads what the
eager press reads, to the round-off of ``compile=True``."""

import math

import pytest
import torch
import trimesh
from test_mesh_stack import _colliders, _points
from test_mpm_compile import needs_compiler

from tvrecon.sim.bodies.mesh_stack import MeshStack, near_blocks
from tvrecon.sim.mpm import particle_contact
from tvrecon.sim.mpm.block_grid import bspline_weights, stencil_shifts
from tvrecon.sim.mpm.compiled import backend
from tvrecon.sim.mpm.particle_contact import contact_setup, mesh_contact
from tvrecon.sim.press import loop as press_loop


def test_near_blocks_and_mesh_contact_equal_the_eager_search():
    """``near_blocks`` of (B, M, 3) blocks is ``MeshStack.near`` of the (B M,) points; ``mesh_contact`` returns the
    eager lookup (``sdf_normal``, +inf beyond one cell) and ``contact_setup``, bit for bit."""
    cols = _colliders()
    stack = MeshStack(cols, "cpu")
    B, M = len(cols), 700
    x = _points(B * M, seed=3)
    scene = torch.arange(B).repeat_interleave(M)
    dx = stack.dx
    ref = stack.near(x, scene, dx)
    blocks = near_blocks(x.view(B, M, 3), stack.lo_index32, stack.cmin_dims, stack.cmin_offset, stack.cmin, dx, dx)
    assert torch.equal(blocks, ref) and 0 < int(ref.sum()) < B * M
    cand = torch.nonzero(ref).flatten()
    # a grid of N nodes and a stencil of 27 weights per particle, as a step hands them over
    g = torch.Generator().manual_seed(0)
    N = 4000
    lin = torch.randint(0, N - 2000, (B * M,), generator=g)
    fxt = 0.5 + torch.rand(3, B * M, generator=g)  # in [0.5, 1.5): the weights come from it
    w_all = torch.stack(bspline_weights(fxt), 0)  # (27, P)
    node_mass = torch.rand(N, generator=g) * (torch.rand(N, generator=g) > 0.2)
    gv = torch.randn(N, 3, generator=g)
    mass, alpha = torch.rand(B * M, generator=g), torch.rand(B * M, generator=g)
    hv = torch.randn(B * M, 3, generator=g)
    shifts = stencil_shifts(100, 10, torch.device("cpu"))
    tables = stack.lookup_tables(x.dtype)
    out = mesh_contact(gv, node_mass, lin, fxt, shifts, cand, scene[cand], x, mass, alpha, hv, *tables, dx, dx, 1e-3)
    phi, n = stack.sdf_normal(x[cand], scene[cand])
    phi = torch.where(phi < dx, phi, torch.full_like(phi, math.inf))
    want = (*contact_setup(gv, node_mass, lin, w_all[:, cand], shifts, cand, mass, alpha, hv, 1e-3), phi, n)
    assert len(out) == len(want) == 8
    for got, exp in zip(out, want):
        assert got.shape[0] in (cand.numel(), 27, 27 * cand.numel())
        assert torch.equal(got, exp)
    assert torch.isfinite(phi).any() and torch.isinf(phi).any(), "candidates within and beyond the reach"


@pytest.mark.slow
@needs_compiler
@pytest.mark.parametrize("refine", [1, 2])
def test_compiled_mesh_press_batch_uses_the_mesh_kernels_and_matches_eager(monkeypatch, refine):
    """Two touches of a mesh in one loop (``press_batch``), compiled vs eager: the same steps, images within 1e-4
    grid cells (the stated tolerance of ``compile=True`` readings), forces within 1e-5; the compiled press ran the
    prefilter and the lookup as their kernels at every step. ``refine`` 2: the object's table twice as fine as the
    grid (``PressConfig.collider_refine``), looked up at its own spacing by the kernels."""
    from tvrecon.sim.press import EIPSimulator, PressConfig
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sensor = SensorConfig(resolution=(12, 12), layers=4)
    press = PressConfig(n_grid=48, contact="particle", collider_refine=refine)
    pos = [[0.0, 0.0, 0.3], [0.3, 0.0, 0.0]]
    dirs = [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]
    monkeypatch.setattr(press_loop, "FREE_FLIGHT", False)  # every step a full one (free flight: test_free_flight.py)
    # the kernels, not the C++ loop of one thread (test_mpm_contact_loop.py)
    monkeypatch.setattr(particle_contact, "mesh_contact_loop_available", lambda *a: False)
    ref = EIPSimulator(sensor, press).press_batch(mesh, pos, dirs)
    used: dict[str, int] = {}
    call = backend.CompiledKernels.__call__

    def counted(self, name, *args):
        used[name] = used.get(name, 0) + 1
        return call(self, name, *args)

    monkeypatch.setattr(backend.CompiledKernels, "__call__", counted)
    new = EIPSimulator(sensor, press, compile=True).press_batch(mesh, pos, dirs)
    steps = max(r.steps for r in new)
    assert used.get("near", 0) >= steps and used.get("mesh_contact", 0) >= steps // 2, used
    for r, n in zip(ref, new):
        assert r.contact and r.image.abs().max() > 0.1 and r.steps == n.steps
        assert (n.image - r.image).abs().max() <= 1e-4
        torch.testing.assert_close(n.force, r.force, rtol=1e-5, atol=1e-7)
