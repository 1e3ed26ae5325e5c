"""Free flight: a step of a rigidly moving state that no body pushes is a translation, without the MLS-MPM transfers.

A press starts its pad moving with the hand at zero stress (``v_p = v_hand``, ``C_p = 0``, ``F_p = I``) a gap in front
of the object, and on the authors' pad about 30% of a touch's steps pass before the pad first meets it. For such a
state one step of paper eq. 5-11 returns the same motion, round-off aside:

- P2G (eq. 5-6): the stress of ``F = I`` is zero (fixed-corotated, eq. 2-3: ``R = I``, ``J = 1``) and ``C = 0``, so
  each node gets ``v_i = sum_p w_ip m_p v / sum_p w_ip m_p = v``;
- the grid update (eq. 7) without damping and without a grid collider leaves it;
- the particle contact (:mod:`tvrecon.sim.mpm.particle_contact`) pushes no particle while every particle's normal
  velocity stays above its floor (``v . n > -phi / dt`` outside the body): :func:`contact_free` tests exactly that, on
  the same candidates and signed distances the step would use, with a margin of ``MARGIN`` of the speed;
- G2P (eq. 8-11): ``v_p = sum_i w_ip v = v`` (the weights sum to 1), also for a hand-held particle whose hand moves
  at ``v`` (eq. 8), ``C_p = 4 / dx^2 sum_i w_ip v (x_i - x_p)^T = 0`` (the B-spline's first moment is zero) and
  ``F_p = (I + dt C_p) F_p = I``.

So the step is ``x += dt v`` (G2P's own advection), with zero contact force. The transfers would add float32
round-off (``C`` of ~1e-9, ``F`` off ``I`` by as much); the readings of a press agree to that round-off
(``tests/sim/mpm/test_free_flight.py``). :class:`FreeFlight` checks the state once (exactly: ``C == 0``, ``F == I``,
every ``v`` equal, the hand moving with it) and trusts the states it made itself after that; free flight ends for good
at the solver's first real step (after it ``C`` is no longer exactly zero).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider, MeshCollider
from tvrecon.sim.bodies.mesh_stack import stacked_sdf_normal
from tvrecon.sim.mpm.compiled.mesh_contact_loop import mesh_contact_loop_available, mesh_search
from tvrecon.sim.mpm.contact_reach import speed_reach
from tvrecon.sim.mpm.particle_contact import (
    PUSH_CAP_CELLS,
    PUSH_OUT,
    MeshStackCache,
    near_surface,
    normal_floor,
    scene_slices,
    stacked_candidates,
)
from tvrecon.sim.mpm.state import ParticleState

__all__ = ["MARGIN", "FreeFlight", "contact_free", "free_of_mesh", "moves_rigidly"]

#: a step is free only when every candidate's normal velocity clears its floor by this fraction of the speed (the real
#: step's gathered velocity differs from v by float32 round-off, ~1e-7 of it)
MARGIN = 1e-3


def moves_rigidly(state: ParticleState, hand_velocity: Tensor | None, alpha: Tensor | None) -> bool:
    """Whether ``state`` is a zero-stress rigid translation that the hand keeps: ``C == 0`` and ``F == I`` exactly,
    every particle's ``v`` the same, and where ``alpha`` is given (paper eq. 8) the hand velocity (3,) or (P, 3)
    equal to it (None: a hand at rest, so ``v`` must be zero)."""
    v0 = state.v[:1]  # (1, 3)
    eye = torch.eye(3, dtype=state.F.dtype, device=state.F.device)
    ok = (state.C == 0).all() & (state.v == v0).all() & (state.F == eye).all()
    if alpha is not None:
        hv = torch.zeros_like(v0) if hand_velocity is None else hand_velocity.reshape(-1, 3)
        ok = ok & (hv == v0).all()
    return bool(ok)  # one host read


def contact_free(
    x: Tensor,
    v: Tensor,
    colliders: Sequence[Collider | None],
    batch: Tensor | None,
    B: int,
    block: int | None,
    dx: float,
    dt: float,
    stack: MeshStackCache | None = None,
    kernels: Callable[..., Tensor] | None = None,
) -> Tensor:
    """0-dim bool: the particle contact of a step from positions ``x`` (P, 3) at velocities ``v`` (P, 3) pushes no
    particle:
    for every candidate within a cell of its body (:func:`~tvrecon.sim.mpm.particle_contact.near_surface`, the step's
    own search; with stacked mesh colliders and the compiled ``kernels``, their prefilter kernel as the compiled step
    runs it), ``normal_floor(phi) - v . n < -MARGIN |v|``. The search stops at ``dt |v|`` (and a slack) where no
    candidate list is kept: no particle farther can fail the test. Not read here: the caller reads it."""
    # a particle farther than dt |v| (1 + MARGIN) is not pushed: the search need not reach a whole cell (speed_reach
    # with one pass and no push-out; its slack 1e-3 covers MARGIN / sqrt(3)), except with a kept list (fixed reach)
    reach: float | Tensor = dx
    if (stack is None or stack.skin <= 0) and v.numel():
        reach = speed_reach(v.abs().amax(), dt, dx, 1, 0.0)
    mesh_only = stack is not None and colliders and all(isinstance(c, MeshCollider) for c in colliders)
    if mesh_only and kernels is not None and isinstance(reach, Tensor) and mesh_contact_loop_available(x, B, block, v):
        # CPU, one thread: the search of the compiled step's C++ loop, the test on the few it finds
        cand, phi, n = mesh_search(x, stack.get(colliders, x.device), reach, block)
        return _free(v[cand], phi, n, dx, dt) if cand.numel() else torch.ones((), dtype=torch.bool, device=x.device)
    if mesh_only:
        mesh, cand, scene = stacked_candidates(x, colliders, batch, reach, stack, block, kernels)
        if not cand.numel():
            return torch.ones((), dtype=torch.bool, device=x.device)
        args = (x, v, cand, scene, *mesh.lookup_tables(x.dtype), mesh.dx, dx, dt)
        # compiled: the lookup and the test as one kernel (eager, ~15 ops over the K candidates every free step). Not
        # for one candidate or one scene: dynamo compiles sizes 1 as graphs of their own, and those come mid-job (a
        # touch pressed alone after its batch diverged), a recompile of a few CPU-s for a step eager does in a ms
        if kernels is None or cand.numel() < 2 or len(colliders) < 2:
            return free_of_mesh(*args)
        return kernels("free_contact", *args)
    cand, _, phi, n = near_surface(x, colliders, scene_slices(batch, B, block), reach, batch, stack, block)
    if not cand.numel():
        return torch.ones((), dtype=torch.bool, device=x.device)
    return _free(v[cand], phi, n, dx, dt)


def _free(vc: Tensor, phi: Tensor, n: Tensor, dx: float, dt: float) -> Tensor:
    """0-dim bool: no candidate of velocity ``vc`` (K, 3) at sdf ``phi`` (K,) with normal ``n`` (K, 3) is pushed."""
    floor = normal_floor(phi.to(vc.dtype), dt, PUSH_OUT, PUSH_CAP_CELLS * dx / dt)  # (K,)
    need = floor - (vc * n.to(vc.dtype)).sum(1)  # > 0: the body pushes
    return (need + MARGIN * vc.abs().amax()).amax() < 0  # NaN: not free


def free_of_mesh(
    x: Tensor,
    v: Tensor,
    cand: Tensor,
    scene: Tensor,
    cell_f64: Tensor,
    cell_i64: Tensor,
    table: Tensor,
    box: Tensor,
    up: Tensor,
    table_dx: float,
    dx: float,
    dt: float,
) -> Tensor:
    """:func:`contact_free`'s test of the K >= 1 candidates ``cand`` (of the (K,) ``scene``) of stacked mesh colliders,
    after the search, as one pure function (the compiled backend runs it as one kernel, ``"free_contact"``): their sdf
    and normals (:func:`~tvrecon.sim.bodies.mesh_stack.stacked_sdf_normal` from ``MeshStack.lookup_tables``,
    ``table_dx`` the tables' node spacing; +inf beyond the reach of one grid cell ``dx``, as the step's search), then
    the floor test. x, v: (P, 3). Returns a 0-dim bool."""
    phi, n = stacked_sdf_normal(x[cand], scene, cell_f64, cell_i64, table, box, up, table_dx)
    phi = torch.where(phi < dx, phi, math.inf)  # beyond the reach (or NaN): no contact, as the step's search
    return _free(v[cand], phi, n, dx, dt)


class FreeFlight:
    """A solver's free-flight steps (``MLSMPM.free_flight``): :meth:`step` returns the translated state, or None when
    the step must be a real one; after :meth:`end` (the solver's first real step) it always returns None.

    With ``defer`` (the solver's ``defer_checks``: a caller that reads the step's pending values, as the press loop
    does) the step is taken on speculation and its contact test left in ``pending`` (0-dim bool) for the caller's
    own host read: where it reads False, it calls :meth:`end` and runs the step again (a real one). A free step then
    costs no host read of its own, on the GPU as on the CPU; the one step taken in vain is a translation."""

    def __init__(self) -> None:
        self.over = False
        self.steps = 0  # free steps taken (a test and the benchmarks count them)
        # the state this made last and the hand it was checked with: (x, v, C, F, hand velocity, alpha)
        self._trusted: tuple[Tensor | None, ...] | None = None
        self.speed: Tensor | None = None  # 0-dim: the largest velocity component of the trusted state (grid speed)
        self._zeros: Tensor | None = None  # (P, 3) zero contact forces, shared by the free steps
        self.last = False  # the last call took a free step
        self.pending: Tensor | None = None  # with defer: the last free step's contact test, for the caller's read

    def end(self) -> None:
        self.over, self.last = True, False
        self._trusted = self.speed = self._zeros = self.pending = None

    def zero_forces(self, like: Tensor) -> Tensor:
        """(P, 3) zeros like ``like`` (one tensor for every free step; its readers do not write to it)."""
        z = self._zeros
        if z is None or z.shape != like.shape or z.dtype != like.dtype or z.device != like.device:
            z = self._zeros = torch.zeros_like(like)
        return z

    def _known(self, state: ParticleState, hand_velocity: Tensor | None, alpha: Tensor | None) -> bool:
        t = self._trusted
        return t is not None and all(
            a is b for a, b in zip(t, (state.x, state.v, state.C, state.F, hand_velocity, alpha), strict=True)
        )

    def step(
        self,
        state: ParticleState,
        colliders: Sequence[Collider | None],
        hand_velocity: Tensor | None,
        alpha: Tensor | None,
        B: int,
        block: int | None,
        dx: float,
        dt: float,
        stack: MeshStackCache | None = None,
        kernels: Callable[..., Tensor] | None = None,
        defer: bool = False,
    ) -> ParticleState | None:
        """``state`` advanced by ``dt`` as a translation when it moves rigidly and no body pushes a particle this step
        (None: run the real step). No autograd (the caller's ``torch.no_grad``). ``kernels``: the solver's compiled
        backend (its mesh prefilter), or None. ``defer``: the contact test is left to the caller (``pending``)."""
        self.last, self.pending = False, None
        if self.over:
            return None
        if not self._known(state, hand_velocity, alpha):
            if not moves_rigidly(state, hand_velocity, alpha):
                return None
            self.speed = state.v.abs().amax() if state.v.numel() else torch.zeros((), device=state.v.device)
        free = contact_free(state.x, state.v, colliders, state.batch, B, block, dx, dt, stack, kernels)
        if not defer and not bool(free):  # one host read
            return None
        new = replace(state, x=state.x + dt * state.v)  # G2P's advection with v unchanged; C, F, v are kept
        self._trusted = (new.x, new.v, new.C, new.F, hand_velocity, alpha)
        self.steps += 1  # with defer also the one the caller refuses
        self.last, self.pending = True, free if defer else None
        return new
