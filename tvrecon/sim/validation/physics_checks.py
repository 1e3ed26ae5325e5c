"""Physics checks of the solver: the scenes and the theory that ``benchmarks/physics/bench_physics.py``
and ``tests/sim/validation/test_physics.py`` share. Nothing here changes the simulator; it drives :class:`MLSMPM`
directly.

Scenes (lengths in grid cells unless said otherwise, domain units = cells * dx):

- :func:`slab_press`: a flat pad (particle slab, contact layer at the bottom) whose back layer is glued to a rigid
  hand (alpha = 0, heavy mount, as the default ``clamped`` pad) moving down at a constant speed onto a rigid sphere
  (:class:`SphereCollider`) whose apex sits ``offset`` cells above a node plane: the classic Hertz set-up (a rigid
  sphere on an elastic layer bonded to a rigid back). Per step: geometric depth, normal force, contact radius.
  With ``holds`` the hand stops at those depths and the pad relaxes (:mod:`.quasi_static`): the values at rest.
- :func:`free_slab_impact`: a free slab thrown at a sphere (no hand): momentum change vs collider impulse.
- :func:`free_oscillation`: a free slab in its first compression mode (no collider, no hand): elastic + kinetic
  energy over time.

Theory (E* = E / (1 - nu^2) for a rigid indenter):

- Hertz, half-space: ``a = sqrt(R d)``, ``F = 4/3 E* sqrt(R) d^1.5``.
- Thin bonded layer (a >> h), Winkler limit: each column of a layer of thickness h bonded to a rigid back is in
  uniaxial strain, ``p = M u / h`` with the P-wave (oedometric) modulus ``M = lambda + 2 mu``; with the sphere's
  gap ``d - r^2 / 2R`` this gives ``a = sqrt(2 R d)``, ``F = pi M R d^2 / h`` (Johnson, Contact Mechanics, 1985,
  sec. 5.8, the compressible thin-layer limit; valid for nu not near 0.5, where the layer locks).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import SphereCollider
from tvrecon.sim.mpm.materials import fixed_corotated_energy, lame_parameters, p_wave_speed
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import MPMConfig, ParticleState, cfl_dt
from tvrecon.sim.validation.quasi_static import hand_schedule, relaxation_damping, relaxation_steps

__all__ = [
    "SlabPress",
    "slab_lattice",
    "slab_press",
    "hertz_force",
    "hertz_radius",
    "winkler_force",
    "winkler_radius",
    "draw_contact_theory",
    "loglog_slope",
    "free_slab_impact",
    "free_oscillation",
    "total_energy",
]


def hertz_force(E: float, nu: float, R: float, d: np.ndarray | float) -> np.ndarray:
    """Hertz force of a rigid sphere of radius R pressed d into an elastic half-space (any consistent units)."""
    d = np.clip(np.asarray(d, dtype=np.float64), 0.0, None)
    return 4.0 / 3.0 * E / (1.0 - nu**2) * math.sqrt(R) * d**1.5


def hertz_radius(R: float, d: np.ndarray | float) -> np.ndarray:
    """Hertz contact radius sqrt(R d)."""
    return np.sqrt(R * np.clip(np.asarray(d, dtype=np.float64), 0.0, None))


def winkler_force(E: float, nu: float, R: float, h: float, d: np.ndarray | float) -> np.ndarray:
    """Thin bonded layer (a >> h, Winkler limit): ``F = pi (lambda + 2 mu) R d^2 / h``."""
    mu, lam = lame_parameters(E, nu)
    d = np.clip(np.asarray(d, dtype=np.float64), 0.0, None)
    return math.pi * (float(lam) + 2.0 * float(mu)) * R * d**2 / h


def winkler_radius(R: float, d: np.ndarray | float) -> np.ndarray:
    """Thin-layer contact radius sqrt(2 R d) (the sphere's profile cut at depth d)."""
    return np.sqrt(2.0 * R * np.clip(np.asarray(d, dtype=np.float64), 0.0, None))


def draw_contact_theory(ax: Any, E: float, nu: float, R: float, h: float, dx: float, depths: np.ndarray) -> None:
    """Draw the Hertz and thin-layer references on a (force, radius) pair of matplotlib axes.

    Args:
        ax: two axes: forces as F / (E* dx^2) against depth, contact radius against depth (cells).
        E, nu: the pad's material; R, h: sphere radius and layer thickness in cells; dx: cell size.
        depths: (D,) depths in cells.
    """
    unit = E / (1 - nu**2) * dx**2
    ax[0].loglog(depths, hertz_force(E, nu, R * dx, depths * dx) / unit, "k:", lw=2, label="Hertz (half-space)")
    thin = winkler_force(E, nu, R * dx, h * dx, depths * dx) / unit
    ax[0].loglog(depths, thin, "r:", lw=2, label=f"thin layer h={h:g}")
    ax[1].plot(depths, hertz_radius(R, depths), "k:", lw=2, label="Hertz sqrt(R d)")
    ax[1].plot(depths, winkler_radius(R, depths), "r:", lw=2, label="thin layer sqrt(2 R d)")


def label_contact_axes(ax: Any, force_title: str, radius_xmin: float, force_ymin: float | None = None) -> None:
    """Axis labels, titles, limits and legends of a (force, radius) pair of axes drawn with :func:`draw_contact_theory`
    (call it after every line is drawn).

    Args:
        ax: the two axes. force_title: the force panel's title. radius_xmin: the radius panel's smallest depth (cells).
        force_ymin: the force panel's lowest F / (E* dx^2), or None (matplotlib's).
    """
    ax[0].set(xlabel="depth d (cells)", ylabel="F / (E* dx^2)", title=force_title, ylim=(force_ymin, None))
    ax[1].set(xlabel="depth d (cells)", ylabel="contact radius a (cells)", title="contact radius")
    ax[1].set_xlim(radius_xmin, None)
    ax[0].legend(fontsize=7)
    ax[1].legend(fontsize=7)


def loglog_slope(x: np.ndarray, y: np.ndarray, lo: float, hi: float) -> float:
    """Least-squares slope of log y vs log x over ``lo <= x <= hi`` and y > 0 (nan with fewer than 3 points)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    m = (x >= lo) & (x <= hi) & (y > 0)
    if m.sum() < 3:
        return float("nan")
    return float(np.polyfit(np.log(x[m]), np.log(y[m]), 1)[0])


def slab_lattice(width: float, thick: float, spacing: float = 0.5) -> Tensor:
    """(P, 3) float32 particle offsets in cells of a square slab ``width`` x ``width`` x ``thick``, centred in x, y,
    the contact layer at z = 0 first (layers, then y, then x), like
    :func:`tvrecon.sim.sensor.elastic_pad.pad_lattice`."""
    n = int(round(width / spacing))
    L = int(round(thick / spacing)) + 1
    i = (torch.arange(n, dtype=torch.float32) - (n - 1) / 2) * spacing
    k = torch.arange(L, dtype=torch.float32) * spacing
    kk, yy, xx = torch.meshgrid(k, i, i, indexing="ij")
    return torch.stack([xx, yy, kk], -1).reshape(-1, 3)


@dataclass
class SlabPress:
    """Per-step record of :func:`slab_press` (one entry per scene, arrays over steps).

    depth: (B, S) geometric depth in cells: hand travel minus the start gap between the rest contact layer (particle
        centres) and the sphere's apex. force: (B, S) normal force on the pad (simulation units). radius: (B, S)
        contact radius in cells from the pressure's second moment, ``a = sqrt(2.5 sum f r^2 / sum f)`` over the
        collider's node forces (exact for a Hertz pressure ``p0 sqrt(1 - r^2 / a^2)``; the particle forces with
        ``contact="particle"``). area_radius: (B, S) ``sqrt(A / pi)`` of the area A in contact, in cells: node columns
        with a collider force (1 cell^2 each), or contact-layer particles with one (spacing^2 each) with
        ``contact="particle"``. offsets: the B apex offsets. hold: (B, S) index of the hold each step belongs to
        (-1 while the hand moves; :func:`quasi_static.hand_schedule`).
    """

    depth: np.ndarray
    force: np.ndarray
    radius: np.ndarray
    area_radius: np.ndarray
    offsets: list[float]
    dx: float
    E: float
    nu: float
    R: float
    thick: float
    particles: int
    steps: int
    hold: np.ndarray | None = None


def slab_press(
    offsets: Sequence[float] = (0.5,),
    *,
    n_grid: int = 128,
    width: float = 32.0,
    thick: float = 6.0,
    R: float = 12.0,
    max_depth: float = 3.0,
    E: float = 3.0,
    nu: float = 0.25,
    speed_fraction: float = 0.1,
    dt: float | None = None,
    speed: float | None = None,
    spacing: float = 0.5,
    mount_mass: float = 100.0,
    contact: str = "grid",
    holds: Sequence[float] = (),
    hold_steps: int | None = None,
    hold_damping: float | None = None,
) -> SlabPress:
    """Press a slab bonded to a rigid hand onto a rigid sphere, one scene per apex offset, batched.

    The contact layer rests 2.5 cells above node plane ``n_grid / 2`` (half-way between node planes, like the press
    of :mod:`tvrecon.sim.press.loop`); the sphere's apex sits ``offset`` cells above that node plane, so the start gap
    is ``2.5 - offset`` cells (no node of the pad touches the sphere at the start). The hand moves down at ``speed``
    (domain units / s; None -> ``speed_fraction`` times the P-wave speed) until ``max_depth``. With ``holds`` it
    stops at each of those depths for ``hold_steps`` steps (step-and-hold, :mod:`quasi_static`; read the
    static values with :func:`quasi_static.hold_means`).

    Args:
        offsets: apex heights above the node plane, in cells (0 = on a node plane).
        n_grid: grid cells across the domain (sets dx only: every length here is in cells).
        width, thick: slab size in cells. R: sphere radius in cells. max_depth: final geometric depth, cells.
        E, nu: material. dt: time step (None -> CFL). spacing: particle spacing in cells.
        mount_mass: mass multiplier of the hand-driven back layer (the default clamped pad's 100).
        contact: ``MPMConfig.contact``: "grid" (node collider; radius from the node forces) or "particle"
            (particle-level contact; radius from the particle forces at the particles' positions).
        holds: depths (cells) where each scene's hand stops for ``hold_steps`` steps (None ->
            :func:`quasi_static.relaxation_steps` of the layer at the CFL step). Empty: a constant-speed
            press.
        hold_damping: grid damping rate (1/s) while every scene holds (dynamic relaxation); None ->
            :func:`quasi_static.relaxation_damping` of the layer, 0 = none.
    """
    dx = 1.0 / n_grid
    cfg = MPMConfig(n_grid=n_grid, E=E, nu=nu, dt=dt, contact=contact)
    solver = MLSMPM(cfg)
    if speed is None:
        speed = speed_fraction * p_wave_speed(E, nu, 1.0)
    lat = slab_lattice(width, thick, spacing)
    P = lat.shape[0]
    B = len(offsets)
    z_plane = 0.5
    x0 = lat * dx + torch.tensor([0.5, 0.5, z_plane + 2.5 * dx])
    back = lat[:, 2] >= lat[:, 2].max() - 1e-6
    alpha = (~back).to(torch.float32).repeat(B)
    hand = torch.tensor([0.0, 0.0, -speed])
    state = ParticleState.create(
        x0.repeat(B, 1),
        hand.expand(B * P, 3).clone(),
        volume=(spacing * dx) ** 3,
        batch=torch.arange(B).repeat_interleave(P),
    )
    state = replace(state, mass=state.mass * torch.where(back, mount_mass, 1.0).repeat(B))
    colliders = [SphereCollider([0.5, 0.5, z_plane + (off - R) * dx], R * dx) for off in offsets]
    gaps = np.array([2.5 - off for off in offsets])
    step_cells = speed * solver.dt / dx
    if holds:
        if hold_steps is None:
            M = float(solver.lam) + 2.0 * float(solver.mu)
            hold_steps = relaxation_steps(thick, p_wave_speed(E, nu, 1.0) * solver.dt / dx, float(solver.mu), M)
        inc, hold = hand_schedule(gaps, step_cells, max_depth, holds, hold_steps)  # (B, S) cells per step
        n_steps = inc.shape[1]
        if hold_damping is None:
            hold_damping = relaxation_damping(float(solver.mu), 1.0, thick * dx)
        relax = replace(cfg, damping=float(hold_damping))
    else:
        n_steps = int(math.ceil((float(gaps.max()) + max_depth) / step_cells))
        inc, hold = np.full((B, n_steps), step_cells), np.full((B, n_steps), -1)
    centre_cells = torch.tensor([0.5, 0.5]) / dx
    forces = np.zeros((B, n_steps))
    radii = np.zeros((B, n_steps))
    area_radii = np.zeros((B, n_steps))
    for s in range(n_steps):
        if holds:  # (B * P, 3): each scene's hand at its own speed this step
            hand = torch.zeros(B * P, 3)
            hand[:, 2] = -torch.from_numpy(inc[:, s] * dx / solver.dt).to(torch.float32).repeat_interleave(P)
            solver.cfg = relax if bool((inc[:, s] == 0).all()) else cfg  # damped only while every hand holds
        base = torch.floor(state.x / dx - 0.5)
        lo = base.view(B, P, 3).amin(1)  # (B, 3) block origins, as mpm_grid.block_layout
        D = [int(v) for v in (base.view(B, P, 3).amax(1) - lo + 3).amax(0).tolist()]
        state = solver.step(state, colliders, hand_velocity=hand, alpha=alpha)
        forces[:, s] = solver.last_force[:, 2].numpy()
        if contact == "particle":  # second moment of the particle forces about the sphere's axis
            fz = solver.last_particle_force(state.mass)[:, 2].view(B, P)
            r2 = ((state.x[:, :2] / dx - centre_cells) ** 2).sum(1).view(B, P)  # (B, P) cells^2
            tot, m2 = fz.sum(1), (fz * r2).sum(1)
            radii[:, s] = torch.where(tot > 0, (2.5 * m2 / torch.where(tot > 0, tot, 1.0)).sqrt(), 0).numpy()
            touching = (fz > 0).sum(1).to(torch.float64) * spacing**2  # (B,) contact area, cells^2
            area_radii[:, s] = (touching / math.pi).sqrt().numpy()
            continue
        transfer, _ = solver.force_source()  # the last step's transfer
        nf = transfer.node_force.view(B, D[0], D[1], D[2], 3)[..., 2]  # (B, X, Y, Z)
        ix = torch.arange(D[0])[None, :, None] + lo[:, 0, None, None]  # (B, X, 1) global node index
        iy = torch.arange(D[1])[None, None, :] + lo[:, 1, None, None]
        r2 = (ix - centre_cells[0]) ** 2 + (iy - centre_cells[1]) ** 2  # (B, X, Y) cells^2
        fz = nf.sum(3)  # (B, X, Y): columns of nodes
        tot = fz.sum((1, 2))
        m2 = (fz * r2).sum((1, 2))
        radii[:, s] = torch.where(tot > 0, (2.5 * m2 / torch.where(tot > 0, tot, 1.0)).clamp(min=0).sqrt(), 0).numpy()
        area_radii[:, s] = ((fz > 0).sum((1, 2)).to(torch.float64) / math.pi).sqrt().numpy()  # node columns, 1 cell^2
    # depth per scene differs by its gap: record travel and shift per scene to a common depth axis
    depth = np.cumsum(inc, 1) - gaps[:, None]  # (B, S)
    return SlabPress(
        depth=depth,
        force=forces,
        radius=radii,
        area_radius=area_radii,
        offsets=list(offsets),
        dx=dx,
        E=E,
        nu=nu,
        R=R,
        thick=thick,
        particles=P * B,
        steps=n_steps,
        hold=hold,
    )


def total_energy(state: ParticleState, solver: MLSMPM) -> tuple[float, float]:
    """(elastic, kinetic) energy of a state: ``sum V0 psi(F)`` and ``1/2 sum m (|v|^2 + dx^2 / 4 |C|^2)`` (the
    affine part of the APIC velocity field, quadratic B-spline inertia ``D = dx^2 / 4``)."""
    psi = fixed_corotated_energy(state.F, solver.mu, solver.lam)
    el = float((state.volume * psi).sum())
    ke = 0.5 * (state.mass * (state.v.square().sum(1) + 0.25 * solver.dx**2 * state.C.square().sum((1, 2))))
    return el, float(ke.sum())


def free_oscillation(
    n_grid: int = 64,
    width: float = 8.0,
    thick: float = 8.0,
    amplitude: float = 0.01,
    periods: float = 4.0,
    E: float = 3.0,
    nu: float = 0.25,
    spacing: float = 0.5,
    dtype: torch.dtype = torch.float32,
) -> dict[str, np.ndarray]:
    """A free slab (no collider, no hand) started in its first compression mode along z, ``v_z = A c cos(pi z / h)``
    (A = ``amplitude`` of the P-wave speed c), run for ``periods`` estimated periods ``2 h / c``.

    Returns t (s), elastic, kinetic and total energy per step (index 0 = start), and ``momentum`` (S+1, 3)."""
    dx = 1.0 / n_grid
    solver = MLSMPM(MPMConfig(n_grid=n_grid, E=E, nu=nu))
    c = p_wave_speed(E, nu, 1.0)
    lat = slab_lattice(width, thick, spacing).to(dtype)
    x0 = lat * dx + torch.tensor([0.5, 0.5, 0.5 + 0.5 * dx], dtype=dtype)
    v0 = torch.zeros_like(x0)
    v0[:, 2] = amplitude * c * torch.cos(math.pi * lat[:, 2] / thick)
    v0 -= v0.mean(0)  # no net momentum
    state = ParticleState.create(x0, v0, volume=(spacing * dx) ** 3)
    n_steps = int(math.ceil(periods * 2.0 * thick * dx / c / solver.dt))
    el, ke, mom = [], [], []
    for s in range(n_steps + 1):
        if s:
            state = solver.step(state)
        e, k = total_energy(state, solver)
        el.append(e)
        ke.append(k)
        mom.append((state.mass[:, None] * state.v).sum(0).double().numpy())
    el_a, ke_a = np.array(el), np.array(ke)
    return {
        "t": np.arange(n_steps + 1) * solver.dt,
        "elastic": el_a,
        "kinetic": ke_a,
        "total": el_a + ke_a,
        "momentum": np.array(mom),
    }


def free_slab_impact(
    n_grid: int = 32,
    width: float = 6.0,
    thick: float = 3.0,
    R: float = 6.0,
    speed_fraction: float = 0.1,
    steps: int = 120,
    E: float = 3.0,
    nu: float = 0.25,
    spacing: float = 0.5,
    dtype: torch.dtype = torch.float32,
    contact: str = "grid",
) -> dict[str, float]:
    """A free slab (alpha = 1, no hand) thrown down, slightly sideways, at a rigid sphere (friction 0.5), with
    ``MPMConfig.contact`` = ``contact``.

    Without a hand the only external force is the collider's, so the change of total momentum ``sum m v`` must equal
    the collider impulse ``sum_steps last_force dt``. Returns the momentum change, the impulse (both (3,)), the
    initial momentum magnitude and the largest relative mismatch ``|dp - J| / |p0|``."""
    dx = 1.0 / n_grid
    solver = MLSMPM(MPMConfig(n_grid=n_grid, E=E, nu=nu, friction=0.5, contact=contact))
    c = p_wave_speed(E, nu, 1.0)
    lat = slab_lattice(width, thick, spacing).to(dtype)
    x0 = lat * dx + torch.tensor([0.5, 0.5, 0.5 + 2.0 * dx], dtype=dtype)
    v = torch.tensor([0.3, 0.1, -1.0], dtype=dtype) * speed_fraction * c
    state = ParticleState.create(x0, v.expand_as(x0).clone(), volume=(spacing * dx) ** 3)
    col = SphereCollider([0.5 + 1.0 * dx, 0.5, 0.5 - R * dx], R * dx)

    def momentum(st: ParticleState) -> np.ndarray:
        return (st.mass[:, None].double() * st.v.double()).sum(0).numpy()

    p0 = momentum(state)
    impulse = np.zeros(3)
    worst = 0.0
    for _ in range(steps):
        state = solver.step(state, col)
        impulse += solver.last_force[0].double().numpy() * solver.dt
        worst = max(worst, float(np.linalg.norm(momentum(state) - p0 - impulse)))
    dp = momentum(state) - p0
    scale = float(np.linalg.norm(p0))
    return {
        "dp": dp,
        "impulse": impulse,
        "p0": scale,
        "rel_error": worst / scale,
        "impulse_rel": float(np.linalg.norm(impulse)) / scale,
        "cfl_dt": cfl_dt(solver.cfg),
    }
