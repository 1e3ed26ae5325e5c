"""The particle contact of stacked mesh colliders as one C++ loop (``compiled.mesh_contact_loop``): its search finds the
particles within the reach that the kernels' search (prefilter, then the sdf) keeps, with their sdf and normals to
float32 round-off, in particle order; the whole loop equals the kernels' set-up and passes of those candidates (the
grid and the forces) with and without friction and the hand's blend; a stencil node outside the grid is refused."""

import math

import pytest
import torch
from test_mesh_stack import _colliders, _points
from test_mpm_compile import needs_compiler

from tvrecon.sim.bodies.mesh_stack import MeshStack
from tvrecon.sim.mpm.block_grid import bspline_weights, stencil_shifts
from tvrecon.sim.mpm.compiled.mesh_contact_loop import fused_mesh_contact, mesh_contact_loop_available, mesh_search
from tvrecon.sim.mpm.particle_contact import ITERATIONS, PUSH_CAP_CELLS, PUSH_OUT, contact_passes, contact_setup

pytestmark = pytest.mark.usefixtures("one_thread")
M = 700  # particles a scene


def _scene(seed: int = 3):
    cols = _colliders()
    stack = MeshStack(cols, "cpu")
    x = _points(len(cols) * M, seed=seed)
    scene = torch.arange(len(cols)).repeat_interleave(M)
    if not mesh_contact_loop_available(x, len(cols), M):
        pytest.skip("the C++ contact loop could not be built here")
    return stack, x, scene


def _kernels_search(stack, x, scene, reach):
    """The kernels' search: the prefilter, then the sdf within the reach."""
    cand = torch.nonzero(stack.near(x, scene, float(reach))).flatten()
    phi, n = stack.sdf_normal(x[cand], scene[cand])
    keep = phi < reach
    return cand[keep], phi[keep], n[keep]


@needs_compiler
@pytest.mark.parametrize("cells", [0.3, 1.0])
def test_the_loops_search_finds_what_the_kernels_keep(cells):
    stack, x, scene = _scene()
    reach = torch.tensor(cells * stack.dx)
    want, phi_w, n_w = _kernels_search(stack, x, scene, reach)
    assert 0 < want.numel() < x.shape[0] // 2
    for pts in (x, x.T.contiguous().T):  # row-major, and a compiled step's channel-first view
        got, phi, n = mesh_search(pts, stack, reach, M)
        assert torch.equal(got, want), "the same particles, in particle order"
        torch.testing.assert_close(phi, phi_w, rtol=1e-5, atol=1e-6 * stack.dx)
        torch.testing.assert_close(n, n_w, rtol=1e-5, atol=1e-6)
    nan = x.clone()
    nan[want[0]] = math.nan
    assert want[0] not in mesh_search(nan, stack, reach, M)[0], "a NaN position is nobody's candidate"


def _grid(P: int, seed: int = 0):
    """A grid of N nodes and each particle's base node and offset, as a step hands them over."""
    g = torch.Generator().manual_seed(seed)
    N = 5000
    lin = torch.randint(0, N - 2000, (P,), generator=g)
    fxt = 0.5 + torch.rand(3, P, generator=g)  # in [0.5, 1.5): the weights come from it
    node_mass = torch.rand(N, generator=g) * (torch.rand(N, generator=g) > 0.2)
    gv = 0.3 * torch.randn(N, 3, generator=g)
    mass = torch.rand(P, generator=g) + 0.5
    return g, N, lin, fxt, node_mass, gv, mass


@needs_compiler
@pytest.mark.parametrize("friction", [0.0, 0.4])
@pytest.mark.parametrize("hand", [False, True])
def test_the_loop_equals_the_kernels_set_up_and_passes(friction, hand):
    stack, x, scene = _scene()
    P, dx, dt = x.shape[0], stack.dx, 1e-3
    g, N, lin, fxt, node_mass, gv, mass = _grid(P)
    alpha = torch.rand(P, generator=g) if hand else None
    hv = torch.randn(P, 3, generator=g) if hand else None
    shifts = stencil_shifts(100, 10, torch.device("cpu"))
    reach = torch.tensor(0.6 * dx)
    cand, phi, n = _kernels_search(stack, x, scene, reach)
    w = torch.stack(bspline_weights(fxt), 0)[:, cand]
    setup = contact_setup(gv, node_mass, lin, w, shifts, cand, mass, alpha, hv, dt)
    tail = (dt, friction, PUSH_OUT, PUSH_CAP_CELLS * dx / dt)
    gv_want, f_want = contact_passes(gv, *setup, phi, n, *tail)
    before = gv.clone()
    gv_got, got, f_got = fused_mesh_contact(
        gv, node_mass, lin, fxt, shifts, x, mass, alpha, hv, stack, reach, M, *tail, ITERATIONS
    )
    assert torch.equal(gv, before), "the caller's grid stays as it was"
    assert torch.equal(got, cand)
    torch.testing.assert_close(gv_got, gv_want, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(f_got, f_want, rtol=1e-5, atol=1e-5 * float(f_want.abs().max()))
    assert f_got.abs().sum() > 0 and not torch.equal(gv_got, gv), "some candidates were pushed"


@needs_compiler
def test_the_loop_refuses_a_stencil_node_outside_the_grid():
    stack, x, scene = _scene()
    P, dx = x.shape[0], stack.dx
    _, N, lin, fxt, node_mass, gv, mass = _grid(P)
    reach = torch.tensor(dx)
    first = int(_kernels_search(stack, x, scene, reach)[0][0])
    lin[first] = N - 1  # its stencil reaches past the last node
    shifts = stencil_shifts(100, 10, torch.device("cpu"))
    with pytest.raises(IndexError, match=f"particle {first}'s stencil leaves the {N}-node grid"):
        args = (gv, node_mass, lin, fxt, shifts, x, mass, None, None, stack, reach, M)
        fused_mesh_contact(*args, 1e-3, 0.0, 0.5, 1.0, 3)
