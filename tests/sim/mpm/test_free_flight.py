"""Free flight (``MLSMPM.free_flight``, :mod:`tvrecon.sim.mpm.free_flight`): a zero-stress pad moving with the hand
is translated, without the transfers, until the particle contact would push it; the states and forces equal those of
full steps to float32 round-off, the first full step comes before the first contact force, and a state that is not
such a translation (stressed, sheared, a hand moving otherwise, grid contact, damping, autograd) is never translated.
A press reads the same with and without it."""

import pytest
import torch
import trimesh
from test_mpm import make_pad
from test_mpm_compile import needs_compiler

from tvrecon.sim.bodies.colliders import SphereCollider
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState
from tvrecon.sim.mpm.free_flight import moves_rigidly

HAND = torch.tensor([0.0, 0.0, -0.3])


def _rigid_pad(n_grid: int = 32, lift: float = 3.0) -> tuple[ParticleState, torch.Tensor]:
    """A pad ``lift`` cells above a sphere's top, moving with the hand at zero stress; its alpha (eq. 8)."""
    dx = 1.0 / n_grid
    x, alpha, vol = make_pad(nx=10, ny=10, nz=4, n_grid=n_grid, center=(0.5, 0.5, 0.6 + lift * dx))
    return ParticleState.create(x, HAND.expand_as(x).clone(), volume=vol), alpha


def _run(solver: MLSMPM, state: ParticleState, alpha: torch.Tensor, steps: int):
    col = SphereCollider((0.5, 0.5, 0.4), 0.2)
    forces, free = [], []
    for _ in range(steps):
        before = solver.flight.steps
        state = solver.step(state, collider=col, hand_velocity=HAND, alpha=alpha)
        forces.append(solver.last_force.clone())
        free.append(solver.flight.steps > before)
    return state, torch.stack(forces), free


def test_free_flight_translates_until_contact_and_equals_full_steps():
    cfg = MPMConfig(n_grid=32, contact="particle")
    state, alpha = _rigid_pad()
    full = MLSMPM(cfg)
    s_ref, f_ref, _ = _run(full, state, alpha, 60)
    flying = MLSMPM(cfg)
    flying.free_flight = True
    s_new, f_new, free = _run(flying, state, alpha, 60)
    n_free = sum(free)
    assert free == [True] * n_free + [False] * (60 - n_free), "free steps first, then full steps for good"
    first_force = int(torch.nonzero(f_ref.abs().amax((1, 2)) > 0)[0])
    assert 0 < n_free <= first_force, "translated only before the first contact force"
    assert flying.flight.over and f_new[:n_free].abs().max() == 0
    for name in ("x", "v", "C", "F"):  # C (~4 / s here) to its float32 round-off, ~3e-6 of its largest
        ref = getattr(s_ref, name)
        torch.testing.assert_close(getattr(s_new, name), ref, rtol=1e-5, atol=1e-5 * float(ref.abs().max()), msg=name)
    torch.testing.assert_close(f_new, f_ref, rtol=1e-4, atol=1e-6 * float(f_ref.abs().max()))


def test_a_free_step_is_the_translation_and_keeps_the_state_exact():
    cfg = MPMConfig(n_grid=32, contact="particle")
    state, alpha = _rigid_pad(lift=6.0)
    solver = MLSMPM(cfg)
    solver.free_flight = True
    new = solver.step(state, collider=SphereCollider((0.5, 0.5, 0.4), 0.2), hand_velocity=HAND, alpha=alpha)
    assert solver.flight.steps == 1
    assert torch.equal(new.x, state.x + solver.dt * state.v)
    assert new.C is state.C and new.F is state.F and new.v is state.v
    assert torch.equal(solver.last_force, torch.zeros(1, 3))
    assert torch.equal(solver.last_particle_force(state.mass), torch.zeros_like(state.x))


@pytest.mark.parametrize("case", ["stressed", "sheared", "spread", "hand", "grid", "damping", "grad"])
def test_what_is_not_a_free_translation_is_stepped_in_full(case):
    contact = "grid" if case == "grid" else "particle"
    cfg = MPMConfig(n_grid=32, contact=contact, damping=1.0 if case == "damping" else 0.0)
    state, alpha = _rigid_pad(lift=6.0)
    hand = HAND
    if case == "stressed":
        state = ParticleState(**{**state.__dict__, "F": state.F * 1.01})
    elif case == "sheared":
        C = state.C.clone()
        C[0, 0, 1] = 1e-6
        state = ParticleState(**{**state.__dict__, "C": C})
    elif case == "spread":
        v = state.v.clone()
        v[3, 2] *= 1.001
        state = ParticleState(**{**state.__dict__, "v": v})
    elif case == "hand":
        hand = 0.5 * HAND
    elif case == "grad":
        state = ParticleState(**{**state.__dict__, "x": state.x.clone().requires_grad_(True)})
    assert moves_rigidly(state, hand, alpha) is (case in ("grid", "damping", "grad"))
    solver = MLSMPM(cfg)
    solver.free_flight = True
    solver.step(state, collider=SphereCollider((0.5, 0.5, 0.4), 0.2), hand_velocity=hand, alpha=alpha)
    assert solver.flight.steps == 0 and solver.flight.over


def _two_touches():
    """A sphere, a small pad 2 cells away with the particle contact, and two touches of it: (mesh, sensor, press,
    positions, directions)."""
    from tvrecon.sim.press import PressConfig
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sensor = SensorConfig(resolution=(12, 12), layers=4)
    press = PressConfig(n_grid=48, contact="particle", gap=2.0)
    return mesh, sensor, press, [[0.0, 0.0, 0.3], [0.3, 0.0, 0.0]], [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]


def test_a_press_reads_the_same_with_free_flight(monkeypatch):
    """Two touches of a mesh in one loop, eager, with and without free flight: the same steps, images within 1e-4
    grid cells (the tolerance of the compiled readings), forces within 1e-4; the approach was translated."""
    from tvrecon.sim.mpm import free_flight
    from tvrecon.sim.press import EIPSimulator, loop

    mesh, sensor, press, pos, dirs = _two_touches()
    monkeypatch.setattr(loop, "FREE_FLIGHT", False)
    ref = EIPSimulator(sensor, press).press_batch(mesh, pos, dirs)
    monkeypatch.setattr(loop, "FREE_FLIGHT", True)
    taken = []
    step = free_flight.FreeFlight.step

    def counted(self, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        out = step(self, *args, **kwargs)
        taken.append(out is not None)
        return out

    monkeypatch.setattr(free_flight.FreeFlight, "step", counted)
    new = EIPSimulator(sensor, press).press_batch(mesh, pos, dirs)
    assert sum(taken) >= 10, f"the approach of 2 cells should be translated, got {sum(taken)} free steps"
    for r, n in zip(ref, new):
        assert r.contact and r.image.abs().max() > 0.1 and r.steps == n.steps
        assert (n.image - r.image).abs().max() <= 1e-4
        torch.testing.assert_close(n.force, r.force, rtol=1e-4, atol=1e-7)


def test_free_of_mesh_is_the_floor_test_on_the_stacked_lookup():
    """``free_of_mesh`` (the kernel ``"free_contact"``) answers the floor test of the stacked lookup: a pad moving
    away from the bodies is free, the same pad moving into them is not, and a NaN velocity is not free."""
    from test_mesh_stack import _colliders, _points

    from tvrecon.sim.bodies.mesh_stack import MeshStack
    from tvrecon.sim.mpm.free_flight import MARGIN, free_of_mesh
    from tvrecon.sim.mpm.particle_contact import PUSH_CAP_CELLS, PUSH_OUT, normal_floor

    cols = _colliders()
    stack = MeshStack(cols, "cpu")
    B, M = len(cols), 700
    x = _points(B * M, seed=5)
    scene = torch.arange(B).repeat_interleave(M)
    dx, dt = stack.dx, 1e-3
    cand = torch.nonzero(stack.near(x, scene, dx)).flatten()
    cand = cand[stack.sdf_normal(x[cand], scene[cand])[0] > 0]  # outside the bodies: nothing pushes them at rest
    phi, n = stack.sdf_normal(x[cand], scene[cand])
    phi = torch.where(phi < dx, phi, torch.full_like(phi, float("inf")))
    assert torch.isfinite(phi).any(), "some candidates within a cell of a body"
    tables = stack.lookup_tables(x.dtype)
    for sign in (1.0, -1.0):  # along the outward normals, 2 cells a step: away from the bodies, then into them
        v = torch.zeros_like(x)
        v[cand] = sign * (2 * dx / dt) * n
        want = normal_floor(phi, dt, PUSH_OUT, PUSH_CAP_CELLS * dx / dt) - (v[cand] * n).sum(1)
        want = bool((want + MARGIN * v[cand].abs().amax()).amax() < 0)
        got = free_of_mesh(x, v, cand, scene[cand], *tables, stack.dx, dx, dt)
        assert got.dim() == 0 and bool(got) is want
        assert want is (sign > 0), "moving away is free, moving in is not"
    v[cand[0]] = float("nan")
    assert not bool(free_of_mesh(x, v, cand, scene[cand], *tables, stack.dx, dx, dt))


@pytest.mark.slow
@needs_compiler
@pytest.mark.parametrize("loop_on", [False, True])
def test_a_compiled_press_tests_its_free_steps_in_one_kernel(monkeypatch, request, loop_on):
    """A compiled press of a mesh: its free steps run the ``"free_contact"`` kernel (``loop_on``: on one CPU thread,
    the search of the C++ contact loop, ``mesh_search``, instead), and it reads what the eager press with free flight
    reads (the same steps, images within 1e-4 grid cells, forces within 1e-5)."""
    from tvrecon.sim.mpm import free_flight, particle_contact
    from tvrecon.sim.mpm.compiled import backend
    from tvrecon.sim.press import EIPSimulator, loop

    mesh, sensor, press, pos, dirs = _two_touches()
    monkeypatch.setattr(loop, "FREE_FLIGHT", True)
    ref = EIPSimulator(sensor, press).press_batch(mesh, pos, dirs)
    used: dict[str, int] = {}
    call = backend.CompiledKernels.__call__

    def counted(self, name, *args):  # noqa: ANN001, ANN002, ANN202
        used[name] = used.get(name, 0) + 1
        return call(self, name, *args)

    search = free_flight.mesh_search

    def searched(*args):  # noqa: ANN002, ANN202
        used["mesh_search"] = used.get("mesh_search", 0) + 1
        return search(*args)

    monkeypatch.setattr(backend.CompiledKernels, "__call__", counted)
    monkeypatch.setattr(free_flight, "mesh_search", searched)
    if loop_on:
        request.getfixturevalue("one_thread")  # the C++ loops' condition
    else:
        for module in (free_flight, particle_contact):
            monkeypatch.setattr(module, "mesh_contact_loop_available", lambda *a: False)
    new = EIPSimulator(sensor, press, compile=True).press_batch(mesh, pos, dirs)
    assert used.get("mesh_search" if loop_on else "free_contact", 0) >= 5, used
    for r, n in zip(ref, new):
        assert r.contact and r.image.abs().max() > 0.1 and r.steps == n.steps
        assert (n.image - r.image).abs().max() <= 1e-4
        torch.testing.assert_close(n.force, r.force, rtol=1e-5, atol=1e-7)
