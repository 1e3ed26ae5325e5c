"""The opt-in ``torch.compile`` path with particle contact (``MPMConfig(contact="particle")``): the compiled P2G and
grid update, the eager contact passes (``step._particle_contact``), then the compiled G2P, equal to the eager
step to float32 round-off. Tolerances as in test_mpm_compile.py (grid contact) where the contact does not amplify
the round-off (see the first test).

Marked slow: compiling the kernels takes ~10-40 s on one CPU core. Skipped where inductor cannot compile.
"""

import pytest
import torch
from test_mpm_compile import _press, needs_compiler

from tvrecon.sim.bodies.colliders import SphereCollider
from tvrecon.sim.mpm import MLSMPM, MPMConfig
from tvrecon.sim.mpm.compiled import backend, kernels, step

#: the pad's centre 1 cell above the sphere (its bottom layer 0.25 cells): particle contact starts when the particles
#: reach the surface, within the first few of the 30 steps
LIFT = 1.0


def _roundoff_close(new: torch.Tensor, ref: torch.Tensor, ref64: torch.Tensor, name: str) -> None:
    """``new`` (compiled, float32) within twice the eager float32 ``ref``'s own error against float64 ``ref64``."""
    err32 = float((ref.double() - ref64).abs().max())
    err = float((new - ref).abs().max())
    bound = 2.0 * err32 + 1e-9 * float(ref64.abs().max())
    assert err <= bound, f"{name}: |compiled - eager| {err:.3g}, eager float32 error {err32:.3g}"


@pytest.mark.slow
@needs_compiler
@pytest.mark.parametrize("batched", [False, True])
def test_compiled_particle_contact_step_equals_eager(batched):
    """x within the grid-contact test's tolerances. The contact turns position round-off into velocity
    (``v_n' = -phi / dt``: one float32 ulp of phi at 0.6 is ~1e-5 in v at this dt), and so into F through C; v, C, F,
    the force per step and the particle forces are held, as C is for grid contact, to the eager float32 step's own
    error against float64 (measured: the compiled step is as close to float64 as the eager one, or closer); F also
    within atol 2e-5 (5e-6 measured; grid contact holds it to 1e-6)."""
    cfg = MPMConfig(n_grid=32, contact="particle")
    eager = MLSMPM(cfg)
    comp = MLSMPM(cfg, compile=True)
    comp.compiled_chunk_size = 256  # several P2G chunks, and a shorter last one (dynamic shapes)
    s_ref, f_ref = _press(eager, 30, batched, lift=LIFT)
    pf_ref = eager.last_particle_force(s_ref.mass)
    s_new, f_new = _press(comp, 30, batched, lift=LIFT)
    pf_new = comp.last_particle_force(s_new.mass)
    solver64 = MLSMPM(cfg)
    s64, f64 = _press(solver64, 30, batched, dtype=torch.float64, lift=LIFT)
    pf64 = solver64.last_particle_force(s64.mass)
    assert comp.compiled, "compilation fell back to eager"
    assert int((f_ref[:, 0, 2] != 0).sum()) > 10, "the pad must touch for many steps"
    assert s_ref.C.abs().max() > 1, "and deform"
    torch.testing.assert_close(s_new.x, s_ref.x, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(s_new.F, s_ref.F, rtol=1e-5, atol=2e-5)  # grid contact: 1e-6 (see the docstring)
    for name in ("v", "C", "F"):
        _roundoff_close(getattr(s_new, name), getattr(s_ref, name), getattr(s64, name), name)
    _roundoff_close(f_new, f_ref, f64, "last_force")
    assert pf_ref.abs().max() > 0
    _roundoff_close(pf_new, pf_ref, pf64, "last_particle_force")
    torch.testing.assert_close(pf_new.sum(0), comp.last_force.sum(0), rtol=1e-4, atol=1e-6)  # nothing lost


@pytest.mark.slow
@needs_compiler
def test_compiled_particle_contact_press_images_match_eager(monkeypatch):
    """A whole particle-contact press (EIPSimulator, a mesh) compiled vs eager: same steps, images within 1e-4 grid
    cells (the stated tolerance of ``compile=True`` readings), force within 1e-5."""
    import trimesh

    from tvrecon.sim.press import EIPSimulator, PressConfig, loop
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    monkeypatch.setattr(loop, "FREE_FLIGHT", False)  # every step a full one (free flight: test_free_flight.py)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sensor, press = SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=48, contact="particle")
    pos, d = [0.0, 0.0, 0.3], [0.0, 0.0, -1.0]
    ref = EIPSimulator(sensor, press).press(mesh, pos, d)
    calls = []
    compiled_contact = step._particle_contact
    monkeypatch.setattr(step, "_particle_contact", lambda *a: calls.append(1) or compiled_contact(*a))
    new = EIPSimulator(sensor, press, compile=True).press(mesh, pos, d)
    assert len(calls) == new.steps > 0, "every step must take the compiled path"
    assert ref.contact and ref.image.abs().max() > 0.1 and ref.steps == new.steps
    assert (new.image - ref.image).abs().max() <= 1e-4
    torch.testing.assert_close(new.force, ref.force, rtol=1e-5, atol=1e-7)


def test_particle_contact_compile_failure_falls_back_to_eager(monkeypatch):
    """A kernel failing in a particle-contact step after the contact passes ran (G2P) leaves the eager step's result
    and readings, bit for bit, and the solver eager from then on. The kernels run uncompiled here (plain functions)."""
    from tvrecon.sim.mpm.compiled.grid import grid_collide

    def g2p_fails(*args):
        raise RuntimeError("no compiler here")

    compiled = backend.CompiledKernels()
    plain = {"stencil": kernels.stencil_base, "index": kernels.block_index, "grid": grid_collide}
    plain.update(polar=kernels.polar_fixed, p2g=kernels.p2g_contrib, g2p=g2p_fails)
    monkeypatch.setattr(backend, "_KERNELS", compiled)
    monkeypatch.setattr(step, "g2p_grid_available", lambda *a: False)  # the kernel, not the C++ gather
    monkeypatch.setattr(compiled, "_fns", plain)
    cfg = MPMConfig(n_grid=32, contact="particle")
    eager = MLSMPM(cfg)
    state, f = _press(eager, 12, lift=LIFT)
    assert f[-1].abs().max() > 0, "the last step must touch"
    comp = MLSMPM(cfg, compile=True)
    col, hand = SphereCollider((0.5, 0.5, 0.4), 0.2), torch.tensor([0.0, 0.0, -0.3])
    alpha = state.F.new_ones(len(state.x))
    with pytest.warns(RuntimeWarning, match="eager"):
        s_new = comp.step(state, collider=col, hand_velocity=hand, alpha=alpha)
    assert not comp.compiled
    s_ref = eager.step(state, collider=col, hand_velocity=hand, alpha=alpha)
    for name in ("x", "v", "C", "F"):
        assert torch.equal(getattr(s_new, name), getattr(s_ref, name)), name
    assert eager.last_force.abs().max() > 0 and torch.equal(comp.last_force, eager.last_force)
    assert torch.equal(comp.last_particle_force(state.mass), eager.last_particle_force(state.mass))
