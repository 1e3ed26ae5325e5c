"""The particle contact (``MPMConfig(contact="particle")``, the press's default) against its naive twin.

:class:`tvrecon.sim.mpm.reference.ReferenceMPM` with ``contact="particle"`` writes the contact of
:mod:`tvrecon.sim.mpm.particle_contact` plainly (dense grid, a loop over the 27 offsets, every particle's sdf and
normal from the collider's public ``sdf`` / ``normal``), one scene at a time. Here ``MLSMPM`` steps small pads pressed
onto a sphere, a tilted plane and trimesh icospheres, batched (contiguous and interleaved scenes, one without a body,
two of mesh bodies only), with the press's hand velocity and alpha (0 on the back layer), and must equal the
per-scene references to float64 round-off: positions, velocities, C, F, the per-scene force ``last_force`` and the
per-particle force ``last_particle_force``. The contact's search and passes may be reorganized freely (batched over
scenes, fused, compiled): this file is what holds the result fixed.

The last tests are the physics control: with the contact the pad stops on the body and is pushed away from it; without
it the same press sinks in.
"""

from __future__ import annotations

import pytest
import torch
import trimesh

from tvrecon.sim.bodies.colliders import MeshCollider, PlaneCollider, SphereCollider
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState, cfl_dt
from tvrecon.sim.mpm.reference import ReferenceMPM

pytestmark = pytest.mark.usefixtures("one_thread")

N_GRID = 32
DX = 1.0 / N_GRID
DTYPE = torch.float64
STEPS = 12
E, NU = 3.0, 0.25


def pad(center: tuple[float, float, float], nx: int = 8, ny: int = 8, nz: int = 5) -> tuple[torch.Tensor, torch.Tensor]:
    """(P, 3) float64 particles at half-cell spacing centred on ``center`` and their (P,) alpha (0 on the top layer,
    the back layer the hand carries, as the press's ``clamped`` profile)."""
    h = 0.5 * DX
    g = torch.stack(torch.meshgrid(torch.arange(nx), torch.arange(ny), torch.arange(nz), indexing="ij"), -1)
    g = g.reshape(-1, 3)
    x = (g.to(DTYPE) + 0.5) * h
    x = x - x.mean(0) + torch.tensor(center, dtype=DTYPE)
    alpha = torch.ones(len(x), dtype=DTYPE)
    alpha[g[:, 2] == nz - 1] = 0.0
    return x, alpha


def pad_above(collider, xy: tuple[float, float], gap_cells: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A pad whose nearest particle is ``gap_cells`` cells from the body (moved along z, a few fixed-point steps)."""
    x, alpha = pad((xy[0], xy[1], 0.75))
    for _ in range(8):
        x = x + torch.tensor([0.0, 0.0, gap_cells * DX - float(collider.sdf(x).min())], dtype=DTYPE)
    return x, alpha


def icosphere_collider(radius: float, offset: tuple[float, float]) -> MeshCollider:
    """A trimesh icosphere (320 faces: its facets tilt the normals) with its top near z = 0.6, ``offset`` cells off
    the pad's centre."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=radius)
    mesh.apply_translation([0.5 + offset[0] * DX, 0.5 + offset[1] * DX, 0.6 - radius])
    return MeshCollider(mesh, n_grid=N_GRID, region=((0.3, 0.3, 0.45), (0.7, 0.7, 0.7)))


def colliders() -> dict[str, object]:
    return {
        # apex 2 cells off the pad's centre: the contact normals tilt and friction matters
        "sphere": SphereCollider((0.5 + 2.0 * DX, 0.5, 0.4), 0.2),
        "plane": PlaneCollider((0.5, 0.5, 0.6), (0.0, 0.3, 1.0)),
        "mesh": icosphere_collider(0.2, (-1.5, 1.0)),
        "mesh2": icosphere_collider(0.12, (1.0, -2.0)),  # a second mesh: scenes of mesh bodies only
        "none": None,
    }


@pytest.fixture(scope="module")
def bodies() -> dict[str, object]:
    return colliders()


def build(bodies: dict[str, object], names: list[str], interleave: bool) -> dict[str, object]:
    """B scenes, one pad per body ("none": a pad with no body, above the sphere), in a contiguous or interleaved
    layout, each with its own hand velocity (a per-particle (P, 3) tensor: down and a little sideways)."""
    xs, alphas, hands = [], [], []
    for b, name in enumerate(names):
        body = bodies[name] if name != "none" else bodies["sphere"]
        x, alpha = pad_above(body, (0.5, 0.5), gap_cells=0.1)
        xs.append(x)
        alphas.append(alpha)
        hands.append(torch.tensor([0.04 * (b + 1), -0.03 * b, -0.3], dtype=DTYPE).expand(len(x), 3))
    P = len(xs[0])
    B = len(names)
    if interleave:  # particle k of scene b at row k B + b: the scenes' particles are not contiguous
        order = torch.arange(P * B).reshape(B, P).T.reshape(-1)
    else:
        order = torch.arange(P * B)
    x = torch.cat(xs)[order]
    return {
        "x": x,
        "alpha": torch.cat(alphas)[order],
        "hand": torch.cat(hands)[order].contiguous(),
        "batch": torch.arange(B).repeat_interleave(P)[order],
        "colliders": [bodies[name] for name in names],
        "B": B,
    }


def run_both(scene: dict[str, object], friction: float, steps: int = STEPS):
    """``MLSMPM(contact="particle")`` on the batched scene and one ``ReferenceMPM(contact="particle")`` per scene, step
    by step; yields (step, fast state, fast last_force (B, 3), fast particle forces (P, 3), reference per scene:
    [(rows (P_b,), x, v, C, F, last_force (3,), last_particle_force (P_b, 3))])."""
    x0, alpha, hand, batch, cols, B = (scene[k] for k in ("x", "alpha", "hand", "batch", "colliders", "B"))
    vol = (0.5 * DX) ** 3
    cfg = MPMConfig(n_grid=N_GRID, E=E, nu=NU, friction=friction, contact="particle")
    dt = cfl_dt(cfg)
    solver = MLSMPM(cfg)
    state = ParticleState.create(x0, hand.clone(), volume=vol, batch=batch)
    refs = []
    for b in range(B):
        rows = torch.nonzero(batch == b).flatten()
        P_b = len(rows)
        eye = torch.eye(3, dtype=DTYPE).expand(P_b, 3, 3).clone()
        ref = ReferenceMPM(N_GRID, dt, E, NU, friction=friction, contact="particle")
        refs.append([rows, ref, x0[rows], hand[rows].clone(), torch.zeros(P_b, 3, 3, dtype=DTYPE), eye])
    for i in range(steps):
        state = solver.step(state, collider=cols, hand_velocity=hand, alpha=alpha)
        out = []
        for b, (rows, ref, x, v, C, F) in enumerate(refs):
            vb = torch.full((len(rows),), vol, dtype=DTYPE)
            x, v, C, F = ref.step(x, v, C, F, vb, vb.clone(), cols[b], hand[rows], alpha[rows])
            refs[b][2:] = [x, v, C, F]
            pf = ref.last_particle_force if ref.last_particle_force is not None else torch.zeros_like(x)
            out.append((rows, x, v, C, F, ref.last_force, pf))
        yield i, state, solver.last_force, solver.last_particle_force(state.mass), out


CASES = [
    pytest.param(["sphere", "plane"], False, id="sphere+plane"),
    pytest.param(["plane", "mesh", "none"], True, id="plane+mesh+none-interleaved"),
    pytest.param(["mesh", "sphere"], False, id="mesh+sphere"),
    pytest.param(["mesh2", "mesh"], True, id="mesh2+mesh-interleaved"),
]


@pytest.mark.parametrize("friction", [0.0, 0.5])
@pytest.mark.parametrize(("names", "interleave"), CASES)
def test_particle_contact_equals_the_naive_twin(bodies, names, interleave, friction):
    scene = build(bodies, names, interleave)
    worst = 0.0
    pressed = [0.0] * scene["B"]
    deepest = [0.0] * scene["B"]
    for _, state, force, particle_force, ref in run_both(scene, friction):
        for b, (rows, x, v, C, F, f_ref, pf_ref) in enumerate(ref):
            fscale = max(float(f_ref.abs().max()), 1e-3)
            errs = {
                "x (cells)": float((state.x[rows] - x).abs().max()) / DX,
                "v": float((state.v[rows] - v).abs().max()),
                "C": float((state.C[rows] - C).abs().max()),
                "F": float((state.F[rows] - F).abs().max()),
                "force (rel.)": float((force[b] - f_ref).abs().max()) / fscale,
                "particle force (rel.)": float((particle_force[rows] - pf_ref).abs().max()) / fscale,
            }
            for what, err in errs.items():
                assert err < 1e-9, (names[b], what, err)
            worst = max(worst, *errs.values())
            pressed[b] = max(pressed[b], float(f_ref.norm()))
            if scene["colliders"][b] is not None:
                deepest[b] = min(deepest[b], float(scene["colliders"][b].sdf(x).min()) / DX)
    # the comparison is not vacuous: every scene with a body was pushed (and some particle found inside it, the
    # push-out branch), the one without was not
    for b, name in enumerate(names):
        assert (pressed[b] > 1e-3) == (name != "none"), (name, pressed[b])
        assert (deepest[b] < 0) == (name != "none"), (name, deepest[b])
    print(f"{names} friction {friction}: largest difference {worst:.2e}")


@pytest.mark.parametrize("solver_kind", ["fast", "reference"])
@pytest.mark.parametrize("body", ["sphere", "plane", "mesh"])
def test_the_contact_stops_the_pad_and_pushes_it_away(bodies, body, solver_kind):
    """Physics control, which fails when the contact is skipped: the hand drives the pad 1.2 cells into the body, the
    contact layer stays out of it (no particle deeper than 0.1 cell), and the force on the pad is nonzero and points
    away from the body (along the mean outward normal at the contact). The same press without a body sinks in (checked
    once, on the fast solver)."""
    col = bodies[body]
    scene = build(bodies, [body], interleave=False)
    x0, alpha, hand = scene["x"], scene["alpha"], scene["hand"]
    steps = 28  # 0.1 cell gap, then ~1.2 cells of hand travel (0.047 cells per step)

    def press(collider):
        cfg = MPMConfig(n_grid=N_GRID, E=E, nu=NU, friction=0.3, contact="particle")
        vol = (0.5 * DX) ** 3
        if solver_kind == "fast":
            solver = MLSMPM(cfg)
            s = ParticleState.create(x0, hand.clone(), volume=vol)
            for _ in range(steps):
                s = solver.step(s, collider=collider, hand_velocity=hand, alpha=alpha)
            return s.x, solver.last_force[0]
        ref = ReferenceMPM(N_GRID, cfl_dt(cfg), E, NU, friction=0.3, contact="particle")
        P = len(x0)
        x, v, C, F = x0, hand.clone(), torch.zeros(P, 3, 3, dtype=DTYPE), torch.eye(3, dtype=DTYPE).repeat(P, 1, 1)
        vb = torch.full((P,), vol, dtype=DTYPE)
        for _ in range(steps):
            x, v, C, F = ref.step(x, v, C, F, vb, vb.clone(), collider, hand, alpha)
        return x, ref.last_force

    x, force = press(col)
    phi = col.sdf(x).to(DTYPE)
    assert float(phi.min()) > -0.1 * DX, float(phi.min()) / DX
    touching = phi < 0.25 * DX
    assert int(touching.sum()) >= 4
    outward = col.normal(x[touching]).to(DTYPE).mean(0)
    assert float(force.norm()) > 1e-2
    assert float(force @ outward) > 0.9 * float(force.norm()) * float(outward.norm())
    if solver_kind == "fast":  # the control: without a contact the hand drives the same pad into the body
        x_free, force_free = press(None)
        assert float(col.sdf(x_free).min()) < -0.8 * DX
        assert float(force_free.norm()) == 0.0
