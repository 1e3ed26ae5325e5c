"""Particle-level rigid contact (``MPMConfig(contact="particle")``, the press's default).

The default collider (:func:`tvrecon.sim.bodies.grid_contact.collide_grid`) acts on grid nodes whose signed distance is
negative. A node carries mass from particles up to 1.5 cells away, so contact starts before the particles reach the
body, and a curved body acts through whole node rings at once (one-cell steps that depend on where the body sits
between node planes). Here the contact is decided at the particles, whose positions are known to sub-cell accuracy,
with the signed distance evaluated exactly at them, and its impulse is applied through the grid:

- a particle at signed distance ``phi >= 0`` moving along the outward normal ``n`` at ``v_n = v . n`` (its G2P
  velocity, paper eq. 8) may approach the body by at most ``phi`` this step: ``v_n' = max(v_n, -phi / dt)`` (a
  speculative contact: it lands on the surface instead of crossing it); a particle already inside (``phi < 0``) is
  sent back out by ``PUSH_OUT`` of its depth: ``v_n' = max(v_n, min(-PUSH_OUT phi / dt, PUSH_CAP_CELLS dx / dt))``;
- the tangential velocity loses ``friction * (v_n' - v_n)`` (Coulomb; 0 = frictionless slip, as on the grid);
- the impulse ``J_p = m_p (v' - v)`` is scattered to the grid with the transfer weights, like the momentum of P2G
  (paper eq. 6), a few times on what is left, and then G2P runs on the corrected grid (:func:`particle_contact_grid`).
  ``J_p / dt`` is the collider's force on particle p; per scene it sums to ``MLSMPM.last_force``, and momentum is
  conserved as on the grid.

Contact therefore starts when a particle (not a node) reaches the surface, whatever the body's offset from the node
planes, and the contact area grows particle by particle (the pad's spacing, 0.5 cells by default). This is the
grid-mediated particle impulse of the contact literature (particle-level detection with the response through the
grid, cf. the penalty contacts of DiffTactile and the particle-grid compatibility of MLS-MPM's CPIC, Hu et al.
2018): detecting on particles but correcting only their velocities would leave the grid free below them (see
:func:`particle_contact_grid`). Everything is torch, batched over scenes (each scene's particles meet only its own
collider), device-agnostic and differentiable where the collider's ``sdf`` and ``normal`` are (the analytic ones,
and ``MeshCollider`` by trilinear interpolation). It adds a search for the particles within a cell of a body (a
collider's optional ``near(points, reach)`` superset first, ``MeshCollider``'s one gather per particle, then the sdf
and normal of those left, in one lookup where the collider has ``sdf_normal``) and small gather/scatter passes over
them (:func:`contact_passes`, one compiled kernel in a compiled step); the grid collider's sdf query of every block
node is skipped.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider, MeshCollider
from tvrecon.sim.bodies.mesh_stack import MeshStack, stacked_sdf_normal
from tvrecon.sim.mpm.block_grid import Stencil, bspline_weights, stencil_shifts
from tvrecon.sim.mpm.compiled.contact import contact_grid_available, fused_contact
from tvrecon.sim.mpm.compiled.mesh_contact_loop import fused_mesh_contact, mesh_contact_loop_available
from tvrecon.sim.mpm.contact_reach import speed_reach
from tvrecon.sim.mpm.state import ParticleState

__all__ = [
    "contact_passes",
    "contact_search_reach",
    "contact_setup",
    "MeshStackCache",
    "mesh_contact",
    "contact_velocity",
    "near_surface",
    "normal_floor",
    "particle_contact_grid",
    "scene_slices",
    "stacked_candidates",
    "stencil_nodes",
]

#: Fraction of its depth a particle found inside a body is moved back out per step (Baumgarte-style correction of the
#: penetration the grid smoothing lets through). With ``ITERATIONS`` = 3: 0.037 cells of penetration at 1.5 cells
#: depth (sphere R = 6 cells, pad 3 cells thick). With one pass it was 0.15, against 0.29 with 0.2 and 0.08 with 1.0;
#: the exponents alike, the force 10% higher at 1.0.
PUSH_OUT = 0.5

#: The push-out never asks for more than this many cells per step (a particle pushed deep inside by a sharp feature
#: comes out over several steps instead of being shot out).
PUSH_CAP_CELLS = 0.05

#: Jacobi passes of the grid-mediated particle impulse per step (:func:`particle_contact_grid`, then G2P).
ITERATIONS = 3


def scene_slices(batch: Tensor | None, B: int, block: int | None) -> list[slice | Tensor]:
    """The particles of each of the B scenes: slices when the layout is contiguous (``block`` particles per scene),
    else (P,) boolean masks of ``batch``."""
    if batch is None:
        return [slice(None)]
    if block is not None:
        return [slice(b * block, (b + 1) * block) for b in range(B)]
    return [batch == b for b in range(B)]


def normal_floor(phi: Tensor, dt: float, push_out: float = 0.0, push_cap: float = math.inf) -> Tensor:
    """(K,) the least outward normal velocity that keeps particles at signed distance ``phi`` (K,) out of the body
    this step: ``-phi / dt`` outside, ``min(-push_out phi / dt, push_cap)`` inside (:func:`contact_velocity`)."""
    out = torch.clamp(-push_out * torch.clamp(phi, max=0.0) / dt, max=push_cap)  # (K,) >= 0
    return out - torch.clamp(phi, min=0.0) / dt


def contact_velocity(
    v: Tensor,
    phi: Tensor,
    n: Tensor,
    dt: float,
    friction: float = 0.0,
    push_out: float = 0.0,
    push_cap: float = math.inf,
) -> Tensor:
    """The velocity of particles at signed distance ``phi`` from a body with outward normal ``n`` after the contact
    (see the module docstring): ``v_n' = max(v_n, -phi / dt)`` outside, ``max(v_n, min(-push_out phi / dt,
    push_cap))`` inside, the tangential part reduced by Coulomb friction.

    Args:
        v: (K, 3) velocities. phi: (K,) signed distances. n: (K, 3) unit outward normals. dt: time step.
        friction: Coulomb coefficient (0 = frictionless slip).
        push_out: fraction of its depth a particle found inside is sent back out this step (0: it only stops).
        push_cap: the largest outward normal velocity the push-out asks for (domain units / s).
    Returns:
        (K, 3) velocities.
    """
    vn = (v * n).sum(1)  # (K,)
    dvn = torch.clamp(normal_floor(phi, dt, push_out, push_cap) - vn, min=0.0)  # (K,) >= 0: what the body adds
    if friction <= 0:
        return v + dvn[:, None] * n
    vt = v - vn[:, None] * n
    vt_norm = vt.norm(dim=1, keepdim=True)
    safe = torch.where(vt_norm > 0, vt_norm, torch.ones_like(vt_norm))
    vt = vt * torch.clamp(1.0 - friction * dvn[:, None] / safe, min=0.0)
    return torch.where((dvn > 0)[:, None], vt + (vn + dvn)[:, None] * n, v)


def near_surface(
    x: Tensor,
    colliders: Sequence[Collider | None],
    scenes: Sequence[slice | Tensor],
    reach: float | Tensor,
    batch: Tensor | None = None,
    stack: MeshStackCache | None = None,
    block: int | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The particles that may be within ``reach`` of their scene's body (the only ones a contact can touch this step).

    Args:
        x: (P, 3) positions. colliders: one collider (or None) per scene. scenes: the particles of each scene
            (:func:`scene_slices`). reach: distance (domain units; a 0-dim tensor too).
        batch: (P,) int64 scene of each particle (None: one scene), for the one-pass search of mesh colliders.
        stack: where the stacked tables of the last colliders are kept between steps (None: the loop over scenes).
        block: particles per scene when ``batch`` is the contiguous layout (``MLSMPM._scenes``), else None.
    Returns:
        their (K,) int64 particle indices, (K,) int64 scene indices, (K,) signed distances and (K, 3) unit normals.
        A particle beyond ``reach`` may be among them with its distance set to +inf (:func:`contact_velocity` leaves
        it as it is, exactly): that saves a host sync per step.
    """
    if stack is not None and colliders and all(isinstance(c, MeshCollider) for c in colliders):
        return _near_stacked(x, colliders, batch, reach, stack, block)
    found: list[tuple[Tensor, Tensor, Tensor, Tensor]] = []
    for b, col in enumerate(colliders):
        if col is None:
            continue
        xb = x[scenes[b]]  # a view for a slice
        rows = None  # the rows of xb still in play (None: all)
        prefilter = getattr(col, "near", None)  # a cheap superset (MeshCollider: least node sdf of the cell)
        if prefilter is not None:
            rows = torch.nonzero(prefilter(xb.detach(), reach)).flatten()
            xb = xb[rows]
        both = getattr(col, "sdf_normal", None)  # one lookup for both (MeshCollider)
        if both is not None:
            phi, n = both(xb)
            keep = torch.nonzero(phi.detach() < reach).flatten()
            phi, n = phi[keep], n[keep]
        else:
            phi = col.sdf(xb)
            keep = torch.nonzero(phi.detach() < reach).flatten()
            phi, n = phi[keep], col.normal(xb[keep])
        if keep.numel():
            rows = keep if rows is None else rows[keep]
            s = scenes[b]
            idx = rows + (s.start or 0) if isinstance(s, slice) else torch.nonzero(s).flatten()[rows]
            found.append((idx, torch.full_like(keep, b), phi.to(x.dtype), n.to(x.dtype)))
    if not found:
        e = torch.zeros(0, dtype=torch.int64, device=x.device)
        return e, e, x.new_zeros(0), x.new_zeros(0, 3)
    return tuple(torch.cat(t) for t in zip(*found))  # type: ignore[return-value]


class MeshStackCache:
    """The :class:`~tvrecon.sim.bodies.mesh_stack.MeshStack` of the last step's colliders (a press asks the same
    colliders every step until a touch finishes), and the contact search's candidates kept over steps.

    With ``skin > 0`` (domain units; the solver sets it from ``MLSMPM.contact_skin``) the search keeps the particles
    within ``reach + skin`` of the bodies, a superset of those within ``reach``, and reuses that list (a Verlet list)
    while no particle has moved more than ``skin`` since: every particle within ``reach`` at a later step is then still
    on it. How far they moved is measured on the device (:meth:`drift_of`) and comes back with the caller's own host
    read (:meth:`set_drift`), so a step that reuses the list pays no host sync for its search. The candidates beyond
    ``reach`` get a distance of +inf and add exact zeros to the contact, so the result is the same as a fresh search."""

    def __init__(self, skin: float = 0.0) -> None:
        self.stack: MeshStack | None = None
        self.skin = float(skin)
        self.searches = 0  # fresh searches (each a host sync): a test and the benchmarks count them
        # the list: (candidates, their scenes, the positions searched, the batch tensor, reach + skin)
        self._list: tuple[Tensor, Tensor, Tensor, Tensor | None, float] | None = None
        self._moved: tuple[Tensor, float] | None = None  # (positions, their host-read drift since the search)

    def get(self, colliders: Sequence[MeshCollider], device: torch.device) -> MeshStack:
        if self.stack is None or not self.stack.matches(colliders, device):
            self.stack = MeshStack(colliders, device)
            self._list = self._moved = None
        return self.stack

    def candidates(self, x: Tensor, batch: Tensor | None, reach: float) -> tuple[Tensor, Tensor] | None:
        """The kept list (candidates, scenes) when it still covers ``reach`` at positions ``x`` (None: search)."""
        kept, moved = self._list, self._moved
        if kept is None or moved is None or moved[0] is not x or kept[3] is not batch:
            return None
        if not moved[1] <= kept[4] - reach:  # also NaN
            return None
        return kept[0], kept[1]

    def keep(self, cand: Tensor, scene: Tensor, x: Tensor, batch: Tensor | None, reach: float) -> None:
        """Remember a fresh search of positions ``x`` with ``reach`` (the skin already added)."""
        self.searches += 1
        self._list = (cand, scene, x.detach(), batch, reach) if self.skin > 0 else None
        self._moved = None

    def drift_of(self, x: Tensor) -> Tensor | None:
        """0-dim: the largest distance a particle at ``x`` has moved since the kept search (None: no list, or the
        particles changed); the caller reads it with its own host read and gives it to :meth:`set_drift`."""
        kept = self._list
        if kept is None or kept[2].shape != x.shape:
            return None
        return (x.detach() - kept[2]).square().sum(1).amax().sqrt()

    def set_drift(self, x: Tensor, drift: float) -> None:
        """The host's value of :meth:`drift_of` for positions ``x`` (the next step's)."""
        self._moved = (x, float(drift))

    def snapshot(self) -> tuple[object, object]:
        """The kept list and its drift as they are now (opaque), for :meth:`restore`: a window of unread steps that
        runs again from its start (``MLSMPM.mark`` / ``MLSMPM.rewind``) starts from the list it had then."""
        return self._list, self._moved

    def restore(self, snapshot: tuple[object, object]) -> None:
        """Back to the kept list and drift of a :meth:`snapshot`."""
        self._list, self._moved = snapshot  # type: ignore[assignment]


def _near_stacked(
    x: Tensor,
    colliders: Sequence[MeshCollider],
    batch: Tensor | None,
    reach: float | Tensor,
    cache: MeshStackCache,
    block: int | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`near_surface` of B mesh colliders in one pass: one prefilter of every particle in its scene's table, one
    compaction (the step's only host sync here, skipped while the cache's kept list still covers ``reach``), one
    lookup; the particles of the prefilter beyond ``reach`` keep a distance of +inf instead of a second compaction."""
    stack, cand, scene = stacked_candidates(x, colliders, batch, reach, cache, block)
    phi, n = stack.sdf_normal(x[cand], scene)
    far = ~(phi.detach() < reach)  # NaN too, as the loop's compaction drops it
    phi = torch.where(far, torch.full_like(phi, math.inf), phi)
    return cand, scene, phi.to(x.dtype), n.to(x.dtype)


def stacked_candidates(
    x: Tensor,
    colliders: Sequence[MeshCollider],
    batch: Tensor | None,
    reach: float | Tensor,
    cache: MeshStackCache,
    block: int | None = None,
    kernels: Callable[..., Tensor] | None = None,
) -> tuple[MeshStack, Tensor, Tensor]:
    """The stacked colliders and the (K,) int64 particles (and their (K,) scenes) that may be within ``reach``: the
    cache's kept list while it still covers ``reach``, else one prefilter of every particle and one compaction.
    ``reach``: a float, or a 0-dim tensor where the cache keeps no list (``skin == 0``). ``kernels``: a compiled
    backend whose ``"near"`` kernel runs the prefilter of a press's contiguous blocks."""
    stack = cache.get(colliders, x.device)
    kept = cache.candidates(x, batch, reach)
    if kept is not None:
        return stack, *kept  # no particle has moved past the skin since the search: the same superset
    scene = torch.zeros(x.shape[0], dtype=torch.int64, device=x.device) if batch is None else batch
    wide = reach + cache.skin
    B = len(colliders)
    if kernels is not None and block is not None and x.shape[0] == block * B:
        pts = x.detach().view(B, block, 3)
        mask = kernels("near", pts, stack.lo_index32, stack.cmin_dims, stack.cmin_offset, stack.cmin, stack.dx, wide)
    else:
        mask = stack.near(x.detach(), scene, wide, block)
    cand = torch.nonzero(mask).flatten()  # (K,)
    scene = scene[cand]
    cache.keep(cand, scene, x, batch, wide)
    return stack, cand, scene


def stencil_nodes(st: Stencil, particles: Tensor | None = None) -> Tensor:
    """(27, K) int64 block-grid index of the 27 stencil nodes (offsets (i, j, k), i slowest) of the K = P particles,
    or of the (K,) int64 ``particles`` only."""
    lin = st.lin if particles is None else st.lin[particles]
    return lin[None, :] + stencil_shifts(st.D[1] * st.D[2], st.D[2], st.lin.device)[:, None]


def contact_passes(
    gv: Tensor,
    flat: Tensor,
    w: Tensor,
    share: Tensor,
    m: Tensor,
    a: Tensor | None,
    hv: Tensor | None,
    phi: Tensor,
    n: Tensor,
    dt: float,
    friction: float,
    push_out: float,
    push_cap: float,
) -> tuple[Tensor, Tensor]:
    """``ITERATIONS`` Jacobi passes of the grid-mediated impulse of K particles near a body
    (:func:`particle_contact_grid`): gather their velocity from the grid (paper eq. 8), :func:`contact_velocity`,
    scatter the impulse ``J_p`` back like momentum (eq. 6).

    Args:
        gv: (N, 3) grid velocities. flat: (27 K,) int64 stencil node of each (node o, particle k) pair, o slowest.
        w: (27, K, 1) transfer weights. share: (27 K, 1) ``w_ip dt / m_i``. m: (K, 1) particle masses.
        a: (K, 1) alpha_p of eq. 8 or None (all ones). hv: (K, 3) hand velocity (with ``a``) or None.
        phi: (K,) signed distances, n: (K, 3) unit outward normals. dt, friction, push_out, push_cap: as
            :func:`contact_velocity`.
    Returns:
        the corrected (N, 3) grid velocities and the (K, 3) collider force on each particle (sum over passes).
    """
    K = phi.shape[0]
    # what the passes share (hoisted: each launch saved here is saved ITERATIONS times a step on a GPU)
    held = None if a is None or hv is None else (1.0 - a) * hv  # (K, 3): the hand's part of paper eq. 8
    scale = m / dt if a is None else a * m / dt  # (K, 1): force per velocity change, alpha_p J_p / (dt dv_p)
    frictionless = friction <= 0
    if frictionless:  # only the normal velocity changes (contact_velocity's v_n' - v_n along n)
        floor_vn = normal_floor(phi, dt, push_out, push_cap)  # (K,)
        pull = scale * n  # (K, 3): the force of a unit normal velocity change
    share = share.view(27, K, 1)
    total = None
    for _ in range(ITERATIONS):
        v = (w * gv[flat].reshape(27, K, 3)).sum(0)  # (K, 3) sum_i w_ip v_i
        if held is not None:
            v = torch.addcmul(held, a, v)  # paper eq. 8 (eq:particle_v): alpha_p v + (1 - alpha_p) v_r
        if frictionless:
            f = torch.clamp(floor_vn - (v * n).sum(1), min=0.0)[:, None] * pull  # (K, 3)
        else:  # Coulomb friction: contact_velocity's tangential branch too
            f = scale * (contact_velocity(v, phi, n, dt, friction, push_out, push_cap) - v)
        gv = gv.index_add(0, flat, (share * f).view(27 * K, 3))  # v_i += sum_p w_ip J_p / m_i
        total = f if total is None else total + f
    return gv, total


def _compiled_passes(kernels: Callable[..., tuple[Tensor, Tensor]], args: tuple) -> tuple[Tensor, Tensor]:
    """:func:`contact_passes` of ``args`` in a compiled step: on the CPU with one thread the C++ loop
    (:mod:`tvrecon.sim.mpm.compiled.contact`, ~3x faster than inductor's atomic scatter), else the compiled kernel."""
    if contact_grid_available(*args[:9]):
        return fused_contact(*args, ITERATIONS)
    return kernels("contact", *args)


def particle_contact_grid(
    state: ParticleState,
    st: Stencil,
    gv: Tensor,
    node_mass: Tensor,
    colliders: Sequence[Collider | None],
    hand_velocity: Tensor | None,
    alpha: Tensor | None,
    B: int,
    block: int | None,
    dt: float,
    dx: float,
    friction: float,
    kernels: Callable[..., tuple[Tensor, Tensor]] | None = None,
    stack: MeshStackCache | None = None,
    speed: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """The rigid bodies' impulses on the particles, applied through the grid velocities ``gv`` (N, 3) before G2P
    (paper eq. 8-11). ``st``: the step's stencil (its ``w`` (27, P), ``lin`` and ``D``); ``node_mass``: the (N,)
    grid mass; ``dt``, ``dx``: the step and cell size; ``friction``: the Coulomb coefficient.

    Returns the corrected (N, 3) grid velocities, the (B, 3) force on each scene's particles (the solver's
    ``last_force``) and the (P, 3) force on each particle, detached (what ``MLSMPM.last_particle_force`` returns).

    Only the particles within a cell of a body can reach it in one step (the grid moves less than a cell per step):
    :func:`near_surface` finds them and their signed distances and normals once. Then ``ITERATIONS`` times: gather
    their velocity (eq. 8) from the grid velocities ``gv`` (N, 3); :func:`contact_velocity` gives the impulse ``J_p =
    m_p dv_p`` that keeps each out of the bodies (and moves one found inside back out by ``PUSH_OUT`` of its depth);
    scatter the impulses to the grid like momentum (eq. 6): ``v_i += sum_p w_ip J_p / m_i``. The caller then runs
    G2P of the corrected grid (eq. 8-11). A particle with ``alpha_p < 1`` follows the grid only in part (eq. 8), so
    its impulse is ``alpha_p J_p``: the rigid hand (``alpha = 0``) is not held by the object (its impulse could never
    reach it and would pile up on the grid).

    The impulse acts through the grid, like any external force, so a held particle's ``C`` (eq. 9) and ``F`` (eq. 11)
    see the held velocity field. (Correcting the particle velocities alone leaves the grid below a held particle free:
    its stress then leaks away through ``C``; measured: half the force at 0.03 of the P-wave speed.) One scatter
    shares a particle's impulse with the neighbours of its nodes, so it is repeated on what is left (Jacobi
    iterations); what the last one leaves lets a particle sink a little, corrected at the next steps.

    ``kernels``: the compiled backend's ``CompiledKernels``, whose ``"contact"`` kernel runs :func:`contact_passes`
    fused (float32 round-off apart), and with stacked mesh colliders its ``"near"`` and ``"mesh_contact"`` kernels
    the prefilter and the rest (:func:`mesh_contact`); None: eager. ``stack``: the solver's :class:`MeshStackCache`,
    so that mesh colliders are searched in one pass over all scenes (None: scene by scene). The eager step passes
    ``node_mass`` with its autograd graph (the impulse share ``w_ip J_p / m_i`` depends on the positions through
    ``m_i`` too); the no-grad compiled step passes the detached grid mass of its transfer.

    The search reaches :func:`~tvrecon.sim.mpm.contact_reach.speed_reach` of the step's speeds (``speed``: 0-dim, the
    largest node velocity component of ``gv``, None: taken here), a bound on how far a pushed particle can be, instead
    of the whole cell (the same step; on the old paper pad 2,949 particles within it a call against 4,687 within a
    cell), except with a kept candidate list (``stack.skin > 0``, the GPU's), whose reach must stay fixed.
    """
    P = state.x.shape[0]
    mu_f = friction
    reach: float | Tensor = dx
    if stack is None or stack.skin <= 0:
        reach = contact_search_reach(gv, speed, hand_velocity, alpha, dt, dx, friction)
    if kernels is not None and stack is not None and colliders and all(isinstance(c, MeshCollider) for c in colliders):
        hv = hand_velocity if hand_velocity is None or hand_velocity.dim() == 2 else hand_velocity[None]
        if isinstance(reach, Tensor) and mesh_contact_loop_available(state.x, B, block, gv, node_mass, alpha, hv):
            # CPU, one thread: search, set-up and passes as one C++ loop, only the candidates within the reach
            mesh = stack.get(colliders, state.x.device)
            stack.searches += 1
            shifts = stencil_shifts(st.D[1] * st.D[2], st.D[2], st.lin.device)
            push_cap = PUSH_CAP_CELLS * dx / dt
            gv, cand, total = fused_mesh_contact(
                gv, node_mass, st.lin, st.fx.T, shifts, state.x, state.mass, alpha, hv, mesh, reach, block, dt, mu_f,
                PUSH_OUT, push_cap, ITERATIONS,
            )  # fmt: skip
            force = gv.new_zeros(B, 3).index_add(0, torch.div(cand, block, rounding_mode="floor"), total)
            return gv, force, gv.new_zeros(P, 3).index_add(0, cand, total)
        # compiled: the prefilter of a press's blocks, the lookup and set-up, the passes: three kernels
        mesh, cand, scene = stacked_candidates(state.x, colliders, state.batch, reach, stack, block, kernels)
        K = cand.numel()
        total = gv.new_zeros(K, 3)
        if K:
            shifts = stencil_shifts(st.D[1] * st.D[2], st.D[2], st.lin.device)
            prep = kernels(
                "mesh_contact",
                gv,
                node_mass,
                st.lin,
                st.fx.T,
                shifts,
                cand,
                scene,
                state.x,
                state.mass,
                alpha,
                hv,
                *mesh.lookup_tables(state.x.dtype),
                mesh.dx,
                dx,
                dt,
            )
            gv, total = _compiled_passes(kernels, (gv, *prep, dt, mu_f, PUSH_OUT, PUSH_CAP_CELLS * dx / dt))
        force = gv.new_zeros(B, 3).index_add(0, scene, total)
        return gv, force, gv.new_zeros(P, 3).index_add(0, cand, total.detach())
    slices = scene_slices(state.batch, B, block)
    cand, scene, phi, n = near_surface(state.x, colliders, slices, reach, state.batch, stack, block)
    K = cand.numel()
    total = gv.new_zeros(K, 3)
    if K:
        shifts = stencil_shifts(st.D[1] * st.D[2], st.D[2], st.lin.device)
        w = st.weights(cand)  # (27, K)
        setup = contact_setup(gv, node_mass, st.lin, w, shifts, cand, state.mass, alpha, hand_velocity, dt)
        args = (gv, *setup, phi, n, dt, mu_f, PUSH_OUT, PUSH_CAP_CELLS * dx / dt)
        gv, total = contact_passes(*args) if kernels is None else _compiled_passes(kernels, args)
    force = gv.new_zeros(B, 3).index_add(0, scene, total)
    return gv, force, gv.new_zeros(P, 3).index_add(0, cand, total.detach())


def contact_search_reach(
    gv: Tensor,
    speed: Tensor | None,
    hand_velocity: Tensor | None,
    alpha: Tensor | None,
    dt: float,
    dx: float,
    friction: float,
) -> Tensor:
    """0-dim: :func:`~tvrecon.sim.mpm.contact_reach.speed_reach` of a step whose node velocities before the contact
    are ``gv`` (N, 3) (``speed``: their largest component when the caller has it, else taken here) and whose hand
    moves at ``hand_velocity`` where ``alpha`` holds particles to it (paper eq. 8)."""
    s = gv.detach().abs().amax() if speed is None else speed.detach()
    if alpha is not None and hand_velocity is not None and hand_velocity.numel():
        s = torch.maximum(s.to(hand_velocity.dtype), hand_velocity.detach().abs().amax())
    return speed_reach(s, dt, dx, ITERATIONS, PUSH_CAP_CELLS * dx / dt, friction)


def contact_setup(
    gv: Tensor,
    node_mass: Tensor,
    lin: Tensor,
    w_cand: Tensor,
    shifts: Tensor,
    cand: Tensor,
    mass: Tensor,
    alpha: Tensor | None,
    hand_velocity: Tensor | None,
    dt: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None, Tensor | None]:
    """What :func:`contact_passes` needs of the K particles ``cand``, after ``gv``: their (27 K,) stencil nodes, (27,
    K, 1) weights, (27 K, 1) shares ``w_ip dt / m_i``, (K, 1) masses, (K, 1) alpha and (K, 3) hand velocity (None
    without ``alpha``). lin: (P,) base node; w_cand: (27, K) weights of the candidates; shifts: the (27,) stencil
    offsets (:func:`tvrecon.sim.mpm.block_grid.stencil_shifts`); node_mass: (N,) grid mass; mass, alpha: (P,);
    hand_velocity: (3,), (1, 3) or (P, 3) or None."""
    K = cand.shape[0]
    idx = lin[cand][None, :] + shifts[:, None]  # (27, K): stencil_nodes of the candidates
    gm = node_mass.to(gv.dtype)[idx]  # (27, K): > 0 where w > 0
    has_mass = gm > 0
    inv_m = torch.where(has_mass, torch.reciprocal(torch.where(has_mass, gm, 1.0)), 0.0)
    w = w_cand.to(gv.dtype)[:, :, None]  # (27, K, 1)
    share = (w * (dt * inv_m)[:, :, None]).reshape(-1, 1)  # (27 K, 1): w_ip dt / m_i
    m = mass[cand, None].to(gv.dtype)  # (K, 1)
    a = hv = None
    if alpha is not None:
        a = alpha[cand, None]  # (K, 1)
        hv = torch.zeros(1, 3, dtype=gv.dtype, device=gv.device) if hand_velocity is None else hand_velocity
        hv = hv.reshape(-1, 3)  # (P, 3), or (1, 3): one for all
        hv = (hv.expand(K, 3) if hv.shape[0] == 1 else hv[cand]).contiguous()  # (K, 3)
    return idx.reshape(-1), w, share, m, a, hv


def mesh_contact(
    gv: Tensor,
    node_mass: Tensor,
    lin: Tensor,
    fxt: Tensor,
    shifts: Tensor,
    cand: Tensor,
    scene: Tensor,
    x: Tensor,
    mass: Tensor,
    alpha: Tensor | None,
    hand_velocity: Tensor | None,
    cell_f64: Tensor,
    cell_i64: Tensor,
    table: Tensor,
    box: Tensor,
    up: Tensor,
    table_dx: float,
    dx: float,
    dt: float,
) -> tuple[Tensor, ...]:
    """Everything :func:`contact_passes` needs of the K candidates ``cand`` (of the (K,) ``scene``) with stacked mesh
    colliders, after the search, as one function (the compiled step runs it as one kernel, ``"mesh_contact"``, and
    the passes as another: one kernel of both was measured ~2x slower with dynamic shapes): their sdf and normals
    (:func:`~tvrecon.sim.bodies.mesh_stack.stacked_sdf_normal` from ``MeshStack.lookup_tables``; +inf beyond the reach
    of one grid cell ``dx``; ``table_dx``: the tables' node spacing, ``dx`` or finer) and :func:`contact_setup`.
    Returns ``contact_setup``'s six values, then the (K,) sdf and (K, 3) normals, as :func:`particle_contact_grid`'s
    eager steps compute them (to round-off)."""
    phi, n = stacked_sdf_normal(x[cand], scene, cell_f64, cell_i64, table, box, up, table_dx)
    phi = torch.where(phi < dx, phi, math.inf)  # beyond the reach (or NaN): no contact, exactly
    w_cand = torch.stack(bspline_weights(fxt[:, cand]), 0)  # (27, K) from the (3, P) fx, no (27, P) table
    return (*contact_setup(gv, node_mass, lin, w_cand, shifts, cand, mass, alpha, hand_velocity, dt), phi, n)
