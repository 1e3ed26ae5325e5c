"""The particle contact's passes as one C++ loop (``compiled.contact.fused_contact``) equal
``particle_contact.contact_passes`` (the inductor kernel's function, run eagerly) to float32 round-off, with and
without friction and the hand's blend; a stencil node outside the grid is refused; a compiled mesh press on one thread
runs them at every step and reads what the eager press reads."""

import math

import pytest
import torch
import trimesh
from test_mpm_compile import needs_compiler

from tvrecon.sim.mpm import particle_contact
from tvrecon.sim.mpm.compiled import contact
from tvrecon.sim.mpm.particle_contact import ITERATIONS, PUSH_CAP_CELLS, PUSH_OUT, contact_passes, contact_setup
from tvrecon.sim.press import loop as press_loop


def _passes_inputs(hand: bool, seed: int = 0):
    """K candidates on an N-node grid sharing nodes, as ``contact_setup`` hands them over: a third beyond the reach
    (phi = +inf), some inside the body (phi < 0)."""
    g = torch.Generator().manual_seed(seed)
    N, P, K, dx, dt = 3000, 900, 300, 1.0 / 32, 1e-3
    lin = torch.randint(0, N - 400, (P,), generator=g)
    cand = torch.randperm(P, generator=g)[:K]
    w = torch.rand(27, K, generator=g)
    w = w / w.sum(0)
    node_mass = torch.rand(N, generator=g) + 0.1
    gv = torch.randn(N, 3, generator=g)
    shifts = torch.tensor([i * 100 + j * 10 + k for i in range(3) for j in range(3) for k in range(3)])
    mass, alpha = torch.rand(P, generator=g) + 0.5, torch.rand(P, generator=g) if hand else None
    hv = torch.randn(P, 3, generator=g) if hand else None
    setup = contact_setup(gv, node_mass, lin, w, shifts, cand, mass, alpha, hv, dt)
    phi = dx * (2 * torch.rand(K, generator=g) - 0.5)
    phi[::3] = math.inf
    n = torch.nn.functional.normalize(torch.randn(K, 3, generator=g), dim=1)
    return (gv, *setup, phi, n), dt, dx


@needs_compiler
@pytest.mark.parametrize("friction", [0.0, 0.4])
@pytest.mark.parametrize("hand", [False, True])
def test_fused_contact_equals_the_passes(one_thread, friction, hand):
    args, dt, dx = _passes_inputs(hand)
    if not contact.contact_grid_available(*args):
        pytest.skip("the fused contact passes could not be built here")
    tail = (dt, friction, PUSH_OUT, PUSH_CAP_CELLS * dx / dt)
    gv_want, f_want = contact_passes(*args, *tail)
    gv_got, f_got = contact.fused_contact(*args, *tail, ITERATIONS)
    assert gv_got.data_ptr() != args[0].data_ptr(), "a new grid: the caller's stays as it was"
    torch.testing.assert_close(gv_got, gv_want, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(f_got, f_want, rtol=1e-5, atol=1e-5 * float(f_want.abs().max()))
    far = torch.isinf(args[-2])
    assert torch.equal(f_got[far], torch.zeros_like(f_got[far])) and f_got[~far].abs().sum() > 0
    one, _ = contact.fused_contact(*args, *tail, 1)
    assert not torch.equal(one, gv_got), "the passes are repeated ``iterations`` times"


@needs_compiler
def test_fused_contact_refuses_a_node_outside_the_grid(one_thread):
    args, dt, dx = _passes_inputs(False)
    if not contact.contact_grid_available(*args):
        pytest.skip("the fused contact passes could not be built here")
    gv, flat, *rest = args
    for bad in (gv.shape[0], -1):
        broken = flat.clone()
        broken[5] = bad
        with pytest.raises(IndexError, match=f"stencil node {bad} is outside the {gv.shape[0]}-node grid"):
            contact.fused_contact(gv, broken, *rest, dt, 0.0, PUSH_OUT, 1.0, ITERATIONS)


@pytest.mark.slow
@needs_compiler
@pytest.mark.parametrize("loop", ["mesh_contact_loop", "passes"])
def test_compiled_mesh_press_runs_the_fused_loops(one_thread, monkeypatch, loop):
    """Two touches of a mesh in one loop, compiled on one thread vs eager: the contact ran as its C++ loop at every
    step with contact candidates (``loop``: the whole contact of the mesh colliders, ``compiled.mesh_contact_loop``;
    or, with that one off, the passes alone after the kernels' search), and the readings are within the tolerances
    of ``compile=True`` (1e-4 cells)."""
    from tvrecon.sim.press import EIPSimulator, PressConfig
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sensor = SensorConfig(resolution=(12, 12), layers=4)
    press = PressConfig(n_grid=48, contact="particle")
    pos, dirs = [[0.0, 0.0, 0.3], [0.3, 0.0, 0.0]], [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]
    monkeypatch.setattr(press_loop, "FREE_FLIGHT", False)  # every step a full one (free flight: test_free_flight.py)
    ref = EIPSimulator(sensor, press).press_batch(mesh, pos, dirs)
    calls = []
    if loop == "passes":
        monkeypatch.setattr(particle_contact, "mesh_contact_loop_available", lambda *a: False)
    name = "fused_contact" if loop == "passes" else "fused_mesh_contact"
    fn = getattr(particle_contact, name)

    def counted(*args):  # noqa: ANN002, ANN202
        calls.append(args[0].shape[0])
        return fn(*args)

    monkeypatch.setattr(particle_contact, name, counted)
    new = EIPSimulator(sensor, press, compile=True).press_batch(mesh, pos, dirs)
    assert len(calls) >= max(r.steps for r in new) // 2, f"the compiled steps must use the {loop} loop here"
    for r, n in zip(ref, new):
        assert r.contact and r.image.abs().max() > 0.1 and r.steps == n.steps
        assert (n.image - r.image).abs().max() <= 1e-4
        torch.testing.assert_close(n.force, r.force, rtol=1e-5, atol=1e-7)
