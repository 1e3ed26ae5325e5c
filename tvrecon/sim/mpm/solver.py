"""MLS-MPM solver (Hu et al. 2018; paper eq. 5-11, the loop body of Algorithm 1) on a sparse local grid, in torch.

Conventions (the simulator contract, ``docs/reference/simulator-contract.md``): domain ``[0, 1)^3``,
``dx = 1 / n_grid``, node ``I`` at ``I dx``; quadratic B-spline weights with ``base = floor(x / dx - 0.5)``,
``fx = x / dx - base``, 27 nodes per particle. One step is :meth:`MLSMPM._p2g` (eq. 5-6), :meth:`MLSMPM._grid_update`
(eq. 7, damping, colliders) and :meth:`MLSMPM._g2p` (eq. 8-11). :class:`tvrecon.sim.mpm.reference.ReferenceMPM` is the
same step written naively (dense grid, a loop over the 27 offsets, SVD): read it first; the tests hold the two equal to
round-off.

Layout (:mod:`tvrecon.sim.mpm.block_grid`): the grid is a block per scene aligned to the global lattice and covering
only the bounding box of that scene's particles (cost follows the particles, not ``n_grid^3``); mass and momentum are
scattered in one fused ``(N, 4)`` ``index_add_``; the 27-node sums are small matrix products against the precomputed
offsets; the polar decomposition is an analytic Newton iteration (``materials.polar_decomposition``). With no input
requiring grad the step runs under ``torch.no_grad``; otherwise the same code is differentiated by autograd.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from tvrecon.sim.bodies.colliders import Collider
from tvrecon.sim.bodies.grid_contact import collide_grid
from tvrecon.sim.mpm.block_grid import (
    Stencil,
    Transfer,
    block_index,
    block_layout,
    bounds_row,
    check_grid_speed,
    dims_from_bounds,
    node_major_scatter,
    scene_bounds,
    share_node_force,
    shift_nodes,
    stencil_offsets,
)
from tvrecon.sim.mpm.compiled.backend import CompiledKernels, CompileFailed, compiled_kernels
from tvrecon.sim.mpm.compiled.grid import ColliderFields
from tvrecon.sim.mpm.compiled.policy import mark_compile_cache_warm
from tvrecon.sim.mpm.compiled.step import fused_step, particle_force
from tvrecon.sim.mpm.free_flight import FreeFlight
from tvrecon.sim.mpm.materials import (
    fixed_corotated_kirchhoff,
    lame_parameters,
    polar_decomposition,
    polar_decomposition_fixed,
)
from tvrecon.sim.mpm.particle_contact import MeshStackCache, particle_contact_grid
from tvrecon.sim.mpm.small_matmul import matmul3
from tvrecon.sim.mpm.state import CONTACT_MODES, MPMConfig, ParticleState, cfl_dt

__all__ = ["MLSMPM"]


@dataclass
class _NextLayout:
    """The next step's block layout, planned at the end of a step (``MLSMPM.defer_checks``)."""

    x: Tensor  # the positions it was computed from (the next step must get this very tensor, unchanged)
    version: int  # x._version then
    base_f: Tensor  # (P, 3) base nodes
    lo_f: Tensor  # (B, 3) per-scene lowest base node
    D: list[int] | None  # block dims, once the caller has read them
    padded: bool = False  # D was not read but given with a margin (:meth:`MLSMPM.trust_next`): clamp the indices


@dataclass
class WindowMark:
    """What :meth:`MLSMPM.mark` keeps of the solver's own state at the start of a window of unread steps, so that
    :meth:`MLSMPM.rewind` can run those steps again from there as if they had never run."""

    layout: _NextLayout | None
    layout_dims: list[int] | None
    layout_padded: bool
    contact_list: object
    contact_moved: object


class MLSMPM:
    """MLS-MPM stepper implementing the simulator contract (paper eq. 5-11; naive twin: ``tvrecon.sim.mpm.reference``).

    Args:
        cfg: solver config.
        device: device of internal constants (states may live on it).
        compile: fuse the per-particle arithmetic of no-grad steps with ``torch.compile``
            (:mod:`tvrecon.sim.mpm.compiled.kernels`; equal to the eager step to float32 round-off, not bit for bit).
            None (default) is off (no environment variable is read; presses switch it with ``PressConfig.compile``).
            Steps that need autograd always run eager; when compiling fails the solver warns once and goes on eager. A
            compiled step returns x, v, C, F as channel-first views (``compiled.step.CF_VIEWS``); the particle
            contact's search runs eager.

    After each ``step``, ``last_force`` is the (B, 3) force the collider(s) exerted on the particles of each scene
    (momentum the collider removed from the grid, divided by dt) and ``dt`` is the step used;
    :meth:`last_particle_force` shares that force out over the particles.
    """

    #: particles per cache-sized block of the stencil passes (no-grad steps on the CPU); 0 = off
    chunk_size: int = 4096
    #: P2G's scatter in the node-major layout (:func:`~tvrecon.sim.mpm.block_grid.node_major_scatter`): None = on CUDA
    #: only
    node_major_p2g: bool | None = None
    #: cells beyond the particle contact's reach kept in its candidate list, reused while no particle has moved this far
    #: (``MeshStackCache``; only when the caller reads ``pending_drift``, as the press loop does); 0 = search every
    #: step. None = 0.5 on CUDA, where each search is a host sync, and 0 on the CPU, where the list's extra candidates
    #: cost more than the searches it saves (paper pad, eager: 1-10% slower per touch at 0.25-0.5, measured)
    contact_skin: float | None = None
    #: the polar decomposition's fixed Newton steps with the convergence test left to the caller's host read
    #: (``pending_polar_ok``; ``materials.polar_decomposition_fixed``) instead of a read each iteration: None = on CUDA
    #: only (the CPU's iterating loop drops converged particles, which pays more than the sync costs there)
    deferred_polar: bool | None = None
    #: a step of a zero-stress rigidly moving state that no body pushes is a translation (:mod:`.free_flight`; equal
    #: to the real step to round-off): tried until the solver's first real step. The press loop turns it on (its pad
    #: starts moving with the hand, a gap from the object: ~30% of the authors' pad's steps). With ``defer_checks``
    #: its contact test comes in ``pending_polar_ok`` (False: the caller calls ``flight.end()`` and steps again)
    free_flight: bool = False

    def __init__(self, cfg: MPMConfig, device: str | torch.device = "cpu", compile: bool | None = None) -> None:
        if cfg.n_grid < 4:
            raise ValueError(f"n_grid must be >= 4, got {cfg.n_grid}")
        if cfg.friction < 0:
            raise ValueError(f"friction must be >= 0, got {cfg.friction}")
        if cfg.damping < 0:
            raise ValueError(f"damping must be >= 0, got {cfg.damping}")
        if cfg.contact not in CONTACT_MODES:
            raise ValueError(f"contact must be one of {CONTACT_MODES}, got {cfg.contact!r}")
        self.cfg = cfg
        self.device = torch.device(device)
        self.dx = 1.0 / cfg.n_grid
        self.inv_dx = float(cfg.n_grid)
        self.mu, self.lam = lame_parameters(cfg.E, cfg.nu)
        if cfg.dt is None:
            self.dt = cfl_dt(cfg)
        else:
            if not cfg.dt > 0:
                raise ValueError(f"dt must be > 0, got {cfg.dt}")
            self.dt = float(cfg.dt)
        self.last_force: Tensor = torch.zeros(1, 3, device=self.device)
        self._last_transfer: Transfer | None = None  # the last step's transfer, for last_particle_force
        # particles per compiled P2G call (compile=True): its (108, chunk) rows and their transposed copy stay in a
        # 1 MiB L2 at 2048 (paper touches ~2-8% faster than 4096 in one process; 1024 pays more calls); 0 = one call
        self.compiled_chunk_size = 2048
        #: the caller reads the grid speed check's value with its own host read (:meth:`_speed_check`)
        self.defer_checks = False
        self.pending_grid_speed: Tensor | None = None
        # with defer_checks, the eager step also lays out the next step's blocks from its new positions: the caller
        # reads ``pending_bounds`` (9,) with its own host read and gives the values back (:meth:`set_next_bounds`)
        self.pending_bounds: Tensor | None = None
        self._next_layout: _NextLayout | None = None
        self._hand_memo: tuple[Tensor, int, Tensor] | None = None  # _hand_cf: the last hand velocity and its copy
        self._consts: dict[tuple, tuple[Tensor, Tensor, Tensor]] = {}
        self._scenes_of: tuple[Tensor, int, int, int | None] | None = None  # (batch, its version, B, block)
        self._kernels: CompiledKernels | None = compiled_kernels() if compile else None
        self._fields = ColliderFields()  # the compiled step's collider sdf on the block grid, kept between steps
        # the particle contact's (P, 3) force per particle of the last step (contact="particle")
        self._particle_contact_force: Tensor | None = None
        # the particle contact's stacked mesh colliders and candidate list, kept between steps
        skin = self.contact_skin if self.contact_skin is not None else (0.5 if self.device.type == "cuda" else 0.0)
        self._mesh_stack = MeshStackCache(skin=skin * self.dx)
        # with defer_checks: how far the particles moved since the contact's kept search (0-dim), for the caller's read
        self.pending_drift: Tensor | None = None
        self._drift_x: Tensor | None = None
        # with defer_checks and deferred_polar: whether every particle's fixed-step polar converged (0-dim bool); when
        # the caller reads False it runs the step again with exact_polar (the iterating loop, which raises on a bad F)
        self.pending_polar_ok: Tensor | None = None
        self.exact_polar = False
        self.last_dims: list[int] | None = None  # the block dims of the last step (eager or compiled)
        self.flight = FreeFlight()  # the free-flight steps taken (``free_flight``)

    @property
    def compiled(self) -> bool:
        """Whether no-grad steps run the fused ``torch.compile`` kernels (False after a failed compile)."""
        return self._kernels is not None

    # ------------------------------------------------------------------ helpers
    def _constants(self, dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
        key = (dtype, device)
        if key not in self._consts:
            o = stencil_offsets(device, dtype)  # (27, 3)
            o_aug_t = torch.cat([torch.ones(27, 1, dtype=dtype, device=device), o], 1)  # (27, 4): [1, o]
            self._consts[key] = (o, o_aug_t, o.to(torch.int64))
        return self._consts[key]

    def _spline_constants(self, dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
        """(1, 3, 1) shift s_k, factor a_k and offset c_k of the quadratic B-spline weight c_k + a_k (f - s_k)^2 of the
        node k = 0, 1, 2 (``_stencil``)."""
        key = ("spline", dtype, device)
        if key not in self._consts:
            rows = torch.tensor([[1.5, 1.0, 0.5], [0.5, -1.0, 0.5], [0.0, 0.75, 0.0]], dtype=dtype, device=device)
            self._consts[key] = tuple(r.view(1, 3, 1) for r in rows)  # type: ignore[assignment]
        return self._consts[key]  # type: ignore[return-value]

    def _scenes(self, batch: Tensor | None) -> tuple[int, int | None]:
        """(B, block) of a state's ``batch``: the scene count and, when ``batch`` is the contiguous layout
        ``arange(B).repeat_interleave(block)``, the particles per scene (else None; see ``block_layout``).

        Remembered for the last ``batch`` tensor (and its in-place version counter): a press steps the same one.
        Inference tensors (made under ``torch.inference_mode``, e.g. data generated inside a Lightning test) have no
        version counter, so they are never remembered."""
        if batch is None:
            return 1, None
        version = None if batch.is_inference() else batch._version
        c = self._scenes_of
        if c is not None and version is not None and c[0] is batch and c[1] == version:
            return c[2], c[3]
        B = int(batch.max()) + 1
        P = batch.shape[0]
        block = P // B if P % B == 0 else None
        if block is not None and not torch.equal(batch, torch.arange(B, device=batch.device).repeat_interleave(block)):
            block = None
        if version is not None:
            self._scenes_of = (batch, version, B, block)
        return B, block

    def needs_grad(self, state: ParticleState, hand_velocity: Tensor | None, alpha: Tensor | None) -> bool:
        """Whether a step of ``state`` with these inputs runs under autograd."""
        if not torch.is_grad_enabled():
            return False
        ts = [state.x, state.v, state.C, state.F, state.volume, state.mass, hand_velocity, alpha, self.mu, self.lam]
        return any(isinstance(t, Tensor) and t.requires_grad for t in ts)

    # ------------------------------------------------------------------ step
    def step(
        self,
        state: ParticleState,
        collider: Collider | Sequence[Collider | None] | None = None,
        hand_velocity: Tensor | None = None,
        alpha: Tensor | None = None,
    ) -> ParticleState:
        """Advance the state by one time step ``self.dt``.

        Args:
            state: particle state (P particles, B scenes).
            collider: None, one collider for every scene, or a sequence of B colliders (None entries allowed).
            hand_velocity: (3,) or (P, 3) robot-hand velocity v_r of paper eq. 8 (None = zero).
            alpha: (P,) weights alpha_p of paper eq. 8 (1 = follow the grid, 0 = follow the hand; None = all ones).

        Returns:
            The new ParticleState (same batch, volume and mass tensors).
        """
        x = state.x
        P = x.shape[0]
        dtype, device = x.dtype, x.device
        if hand_velocity is not None:
            hand_velocity = torch.as_tensor(hand_velocity, dtype=dtype, device=device)
            if hand_velocity.shape not in ((3,), (P, 3)):
                raise ValueError(f"hand_velocity must be (3,) or (P, 3) with P={P}, got {tuple(hand_velocity.shape)}")
        if alpha is not None:
            alpha = torch.as_tensor(alpha, dtype=dtype, device=device)
            if alpha.shape != (P,):
                raise ValueError(f"alpha must be a (P,) tensor with P={P}, got {tuple(alpha.shape)}")
        B, block = self._scenes(state.batch)
        if collider is None or not isinstance(collider, Sequence):
            colliders: list[Collider | None] = [collider] * B
        else:
            colliders = list(collider)
            if len(colliders) != B:
                raise ValueError(f"collider sequence must have one entry per scene (B={B}), got {len(colliders)}")
        self.pending_polar_ok = None
        grad = self.needs_grad(state, hand_velocity, alpha)
        if self.free_flight and not self.flight.over:
            new = None
            if not grad and self.cfg.contact == "particle" and self.cfg.damping == 0:
                with torch.no_grad():
                    try:
                        new = self.flight.step(
                            state, colliders, hand_velocity, alpha, B, block, self.dx, self.dt, self._mesh_stack,
                            self._kernels, defer=self.defer_checks,
                        )  # fmt: skip
                    except CompileFailed:  # the compiled prefilter failed (warned once): eager from now on
                        self._kernels = None
            if new is not None:
                self._after_free_step(state, new, B)
                return new
            self.flight.end()  # a real step from here on
        if grad:
            new = self._step(state, colliders, hand_velocity, alpha, B, block)
        else:
            with torch.no_grad():
                new = None
                if self._kernels is not None:  # opt-in fused kernels (compile=True)
                    try:
                        new = self._fused_step(state, colliders, hand_velocity, alpha, B, block)
                    except CompileFailed:
                        self._kernels = None  # warned once; eager from now on
                if new is None:
                    new = self._step(state, colliders, hand_velocity, alpha, B, block)
        self._plan_drift(new)
        return new

    def _after_free_step(self, state: ParticleState, new: ParticleState, B: int) -> None:
        """What a real step leaves for its caller, after a free-flight step: no contact force, the grid speed of the
        translation (the nodes carry the particles' v), the contact test (``pending_polar_ok``) and drift."""
        self.last_force = state.x.new_zeros(B, 3)
        self._particle_contact_force = self.flight.zero_forces(state.x)
        self._speed_check(self.flight.speed)
        self.pending_polar_ok = self.flight.pending  # with defer_checks: the caller reads the contact test here
        # no layout planned: a window of free steps (PressLoop.read_every) then trusts no block dims, and the first
        # real step reads its own bounds
        self._next_layout, self.pending_bounds = None, None
        self._plan_drift(new)

    def _plan_drift(self, state: ParticleState) -> None:
        """With ``defer_checks``: ``pending_drift``, how far the particles of ``state`` moved since the particle
        contact's kept search (None: no list), for the caller's host read (:meth:`set_drift`)."""
        self.pending_drift, self._drift_x = None, None
        if self.defer_checks and self.cfg.contact == "particle":
            with torch.no_grad():
                self.pending_drift = self._mesh_stack.drift_of(state.x)
            self._drift_x = state.x

    def set_drift(self, drift: float) -> None:
        """The host's value of ``pending_drift``: while it stays within the skin, the next step's contact reuses its
        candidate list instead of a search with a host sync."""
        if self._drift_x is not None:
            self._mesh_stack.set_drift(self._drift_x, drift)

    def _step(
        self,
        state: ParticleState,
        colliders: list[Collider | None],
        hand_velocity: Tensor | None,
        alpha: Tensor | None,
        B: int,
        block: int | None = None,
    ) -> ParticleState:
        """One step in the paper's order: P2G (eq. 5-6), grid velocity and colliders (eq. 7), G2P (eq. 8-11)."""
        st = self._stencil(state, B, block)
        grid = self._p2g(state, st)
        if self.cfg.contact == "particle":  # opt-in: the colliders act on the particles (particle_contact.py)
            gv = self._grid_update(grid, [None] * B, st)
            # grid[0]: the node mass with its graph (the transfer keeps it detached), so that d(1 / m_i)/dx reaches
            # autograd through the contact's impulse share w_ip J_p / m_i
            gv, self.last_force, self._particle_contact_force = particle_contact_grid(
                state,
                st,
                gv,
                grid[0],
                colliders,
                hand_velocity,
                alpha,
                B,
                block,
                self.dt,
                self.dx,
                self.cfg.friction,
                stack=self._mesh_stack,
            )
        else:
            gv = self._grid_update(grid, colliders, st)
        new = self._g2p(state, st, gv, hand_velocity, alpha)
        if self.defer_checks:
            self._plan_layout(new, B, block)
        return new

    def _polar(self, F: Tensor) -> Tensor:
        """R of F = R S (paper eq. 4's fixed-corotated stress): the iterating Newton loop, or with ``deferred_polar``
        its fixed steps whose convergence the caller reads (``pending_polar_ok``) or, without ``defer_checks``, this
        step reads once (instead of once per iteration)."""
        self.pending_polar_ok = None
        if not self._deferred_polar(F.device) or self.exact_polar:
            return polar_decomposition(F)
        R, ok = polar_decomposition_fixed(F)
        if self.defer_checks:
            self.pending_polar_ok = ok
            return R
        return R if bool(ok) else polar_decomposition(F)

    def _deferred_polar(self, device: torch.device) -> bool:
        """Whether the polar decomposition runs its fixed steps with the convergence test left to a read
        (``deferred_polar``; None = on CUDA)."""
        return self.deferred_polar if self.deferred_polar is not None else device.type == "cuda"

    def _plan_layout(self, state: ParticleState, B: int, block: int | None) -> None:
        """The next step's base nodes and scene bounds from ``state`` (the step's result), so that its block dims come
        with the caller's host read (``pending_bounds``) instead of a read of their own."""
        if state.x.is_inference():  # no version counter to tell an in-place change: the next step reads its own
            return
        base_f = torch.floor(state.x.detach() * self.inv_dx - 0.5)  # the same values _stencil computes
        lo_f, hi_f = scene_bounds(base_f, state.batch, B, block)
        self._next_layout = _NextLayout(state.x, state.x._version, base_f, lo_f, None)
        self.pending_bounds = bounds_row(lo_f, hi_f)

    def set_next_bounds(self, bounds: list[float], B: int) -> None:
        """The host's values of ``pending_bounds`` (9 floats): the next step on the same state uses them for its
        block dims. Raises FloatingPointError on a non-finite or exploded state, as that step would have."""
        if self._next_layout is not None:
            self._next_layout.D = dims_from_bounds(bounds, B)

    # ------------------------------------------------------------------ windows of unread steps (PressLoop.read_every)
    @property
    def contact_skin_domain(self) -> float:
        """The particle contact's kept-list skin in domain units (0: a search every step)."""
        return self._mesh_stack.skin

    def trust_next(self, dims: list[int]) -> None:
        """Set up the next step without the caller's host read of this one: its block dims are ``dims`` (a margin over
        what was last read; the indices are clamped into the block, so a particle outside it cannot index out of
        range) and the contact reuses its kept candidate list as if no particle had moved. The caller checks both
        with its later read of this step's ``pending_bounds`` and ``pending_drift`` and, where either did not hold,
        rewinds (:meth:`rewind`) and steps again with a read each step."""
        if self._next_layout is not None:
            self._next_layout.D, self._next_layout.padded = list(dims), True
        if self._drift_x is not None:
            self._mesh_stack.set_drift(self._drift_x, 0.0)

    def mark(self) -> WindowMark:
        """The solver's own state now (the next step's planned layout, the contact's kept list)."""
        plan, ms = self._next_layout, self._mesh_stack
        return WindowMark(plan, None if plan is None else plan.D, plan is not None and plan.padded, *ms.snapshot())

    def rewind(self, mark: WindowMark) -> None:
        """Back to :meth:`mark`'s state: the next step is the one that followed it."""
        if mark.layout is not None:
            mark.layout.D, mark.layout.padded = mark.layout_dims, mark.layout_padded
        self._next_layout = mark.layout
        self._mesh_stack.restore((mark.contact_list, mark.contact_moved))

    def force_source(self) -> tuple[Transfer | None, Tensor | None]:
        """What :meth:`last_particle_force` reads of the last step (references), to share that step's force out
        later, after further steps."""
        return self._last_transfer, self._particle_contact_force

    def _fused_step(
        self,
        state: ParticleState,
        colliders: list[Collider | None],
        hand_velocity: Tensor | None,
        alpha: Tensor | None,
        B: int,
        block: int | None,
    ) -> ParticleState:
        """One no-grad step of the compiled backend (:func:`tvrecon.sim.mpm.compiled.step.fused_step`); stores its
        force, transfer and particle contact forces as :meth:`_step` does."""
        x = state.x
        o_int = self._constants(x.dtype, x.device)[2]
        plan, self._next_layout, self.pending_bounds = self._next_layout, None, None
        # the GPU's layout (deferred_polar, e.g. on CUDA) with the caller's deferred reads: the block dims come with
        # the last step's read (planned below), the polar's convergence with this one's; elsewhere the compiled
        # stencil reads its own bounds and the step its polar flag (on the CPU a read is a function return)
        deferred = self.defer_checks and self._deferred_polar(x.device)
        planned = plan is not None and plan.D is not None and plan.x is x and plan.version == x._version
        out = fused_step(
            self._kernels, self._fields, state, colliders, hand_velocity, alpha, B, block,
            self.cfg, self.dt, self.mu, self.lam, self._compiled_chunk(x.device), o_int, self._mesh_stack,
            dims=plan.D if planned else None, padded=planned and plan.padded,
            defer_polar=deferred, exact_polar=self.exact_polar, hand_cf=self._hand_cf(hand_velocity),
        )  # fmt: skip
        self.last_dims = out.dims
        self.pending_polar_ok = out.polar_ok
        if deferred and (state.batch is None or block is not None):
            self._plan_layout(out.state, B, block)
        self.last_force, self._last_transfer = out.force, out.transfer
        mark_compile_cache_warm()  # once per process: compile="auto" takes the warm threshold from now on
        self._speed_check(out.vmax)
        if out.particle_force is not None:
            self._particle_contact_force = out.particle_force
        return out.state

    def _hand_cf(self, hand_velocity: Tensor | None) -> Tensor | None:
        """The (3, P) channel-first copy of a (P, 3) hand velocity for the compiled G2P, kept while the caller passes
        the same tensor unchanged (the press loop does, step after step): no (P, 3) transpose copy per step. None for
        any other hand velocity (the step makes its own)."""
        if hand_velocity is None or hand_velocity.dim() != 2 or hand_velocity.requires_grad:
            return None
        memo = self._hand_memo
        if memo is None or memo[0] is not hand_velocity or memo[1] != hand_velocity._version:
            memo = self._hand_memo = (hand_velocity, hand_velocity._version, hand_velocity.T.contiguous())
        return memo[2]

    def _stencil(self, state: ParticleState, B: int, block: int | None = None) -> Stencil:
        """Particle -> node stencil: base = floor(x/dx - 0.5), fx = x/dx - base, quadratic B-spline weights."""
        x = state.x
        P = x.shape[0]
        Xg = x * self.inv_dx
        plan, self._next_layout, self.pending_bounds = self._next_layout, None, None
        if plan is not None and plan.D is not None and plan.x is x and plan.version == x._version:
            base_f, D = plan.base_f, plan.D  # laid out by the last step, its dims read with the caller's read
            lo, lin = block_index(base_f, plan.lo_f, state.batch, B, block, D, clamp=plan.padded)
        else:
            base_f = torch.floor(Xg.detach() - 0.5)  # (P, 3)
            lo, lin, D = block_layout(base_f, state.batch, B, block)
        self.last_dims = D
        fx = Xg - base_f  # (P, 3) in [0.5, 1.5)
        # channel-first layouts (..., P) below: every big elementwise op runs over contiguous particle rows
        fxt = fx.T.contiguous()  # (3, P)
        # quadratic B-spline 0.5 (1.5 - f)^2, 0.75 - (f - 1)^2, 0.5 (f - 0.5)^2 of the three nodes k along each axis,
        # as c_k + a_k (f - s_k)^2 in three launches (the same roundings: the squares, 0.5 x, 0.75 - x are exact ops)
        shift, coef, bias = self._spline_constants(fx.dtype, fx.device)  # (1, 3, 1) each
        u = fxt[:, None, :] - shift  # (axis, k, P)
        wa = torch.addcmul(bias, u * u, coef)  # (axis, k, P)
        w = (wa[0][:, None, None] * wa[1][None, :, None] * wa[2][None, None, :]).reshape(27, P)  # o = (i, j, k)
        return Stencil(fx, w, lo, lin, D, B * D[0] * D[1] * D[2], self._chunk(P, x.device))

    def _p2g(self, state: ParticleState, st: Stencil) -> Tensor:
        """Scatter mass and momentum to the grid (paper eq. 5 and 6): the (4, N) block grid of [m_i, (m v)_i]."""
        x, v, C, F = state.x, state.v, state.C, state.F
        P = x.shape[0]
        dtype, device = x.dtype, x.device
        dx, inv_dx, dt = self.dx, self.inv_dx, self.dt
        fx, w, lin, D, n_nodes, chunk = st.fx, st.w, st.lin, st.D, st.n_nodes, st.chunk
        _, o_aug_t, _ = self._constants(dtype, device)

        # stress P F^T (paper eq. 4, eq:PK; materials.py) and the affine momentum matrix
        # A = m C - gamma P F^T, gamma = 4 dt V0 / dx^2: the particle term of paper eq. 6 (eq:momentum)
        R = self._polar(F)
        tau = fixed_corotated_kirchhoff(F, self.mu, self.lam, R)  # (P, 3, 3) = P(F) F^T
        m = state.mass
        A = m[:, None, None] * C - ((4.0 * dt * inv_dx * inv_dx) * state.volume)[:, None, None] * tau
        # per node: w * (m v + A (x_i - x_p)) with x_i - x_p = (o - fx) dx  ->  w * (M [1, o]) with M (P, 4, 4)
        mv0 = m[:, None] * v - dx * matmul3(A, fx[:, :, None])[:, :, 0]  # (P, 3)
        MT = torch.cat(
            [
                torch.cat([m[None], torch.zeros_like(mv0.T)], 0)[None],  # (1, 4, P)
                torch.cat([mv0.T[:, None, :], dx * A.permute(1, 2, 0)], 1),  # (3, 4, P)
            ],
            0,
        )  # (4, 4, P): M[c, j] with [1, o] weights j

        # paper eq. 5 (eq:mass) and eq. 6 (eq:momentum): ONE scatter of each particle's whole 4 x 27 stencil onto its
        # base node (P columns of 108), then the 27 stencil offsets are summed by shifting along the node axis, k then
        # j then i (9 shifts).
        S0, S1 = D[1] * D[2], D[2]
        if chunk >= P and (device.type == "cuda" if self.node_major_p2g is None else self.node_major_p2g):
            return node_major_scatter(MT, w, o_aug_t, lin, n_nodes, S0, S1)
        if chunk >= P:
            contrib = torch.matmul(o_aug_t, MT) * w  # (4, 27, P): (m, m v) per stencil node
            G = torch.zeros(108, n_nodes, dtype=dtype, device=device).index_add(1, lin, contrib.reshape(108, P))
        else:  # no autograd: the same sums in particle chunks that stay in cache
            G = torch.zeros(108, n_nodes, dtype=dtype, device=device)
            for s0 in range(0, P, chunk):
                sl = slice(s0, s0 + chunk)
                contrib = torch.matmul(o_aug_t, MT[:, :, sl]).mul_(w[:, sl])
                G.index_add_(1, lin[sl], contrib.view(108, -1))
        Gt = G.view(4, 3, 3, 3, n_nodes)  # (c, i, j, k, node)
        T = Gt[:, :, :, 0] + shift_nodes(Gt[:, :, :, 1], 1) + shift_nodes(Gt[:, :, :, 2], 2)  # (4, 3, 3, N)
        U = T[:, :, 0] + shift_nodes(T[:, :, 1], S1) + shift_nodes(T[:, :, 2], 2 * S1)  # (4, 3, N)
        return U[:, 0] + shift_nodes(U[:, 1], S0) + shift_nodes(U[:, 2], 2 * S0)  # (4, N): mass, momentum

    def _grid_update(self, grid: Tensor, colliders: list[Collider | None], st: Stencil) -> Tensor:
        """Grid velocity (paper eq. 7), damping and colliders; sets ``last_force``. Returns the (N, 3) velocities.

        Raises FloatingPointError when a node would move more than one cell per step (or is NaN)."""
        dt = self.dt
        gm = grid[0]
        has_mass = gm > 0
        # paper eq. 7 (eq:grid_velocity), zero where m = 0
        gv = (grid[1:] / torch.where(has_mass, gm, torch.ones_like(gm))).T  # (N, 3)

        # grid operations: damping, colliders (momentum removed -> force)
        if self.cfg.damping > 0:
            gv = gv * math.exp(-self.cfg.damping * dt)
        gv, force, node_force = collide_grid(gv, gm, colliders, st.lo, st.D, self.dx, dt, self.cfg.friction)
        self.last_force = force
        S0, S1 = st.D[1] * st.D[2], st.D[2]
        self._last_transfer = Transfer(st.lin, st.w.detach(), gm.detach(), node_force.detach(), (S0, S1))
        self._speed_check(gv.detach().abs().amax() if st.n_nodes else None)
        return gv

    def _g2p(
        self,
        state: ParticleState,
        st: Stencil,
        gv: Tensor,
        hand_velocity: Tensor | None,
        alpha: Tensor | None,
    ) -> ParticleState:
        """Gather the grid velocities back to the particles and advance them (paper eq. 8-11)."""
        x, F = state.x, state.F
        P = x.shape[0]
        dtype, device = x.dtype, x.device
        inv_dx, dt = self.inv_dx, self.dt
        fx, w, lin, D, n_nodes, chunk = st.fx, st.w, st.lin, st.D, st.n_nodes, st.chunk
        _, o_aug_t, _ = self._constants(dtype, device)
        S0, S1 = D[1] * D[2], D[2]

        # table H[node, c, o] = v_c(node + offset_o) from 9 shifts; a row gather per particle
        gvc = gv.T  # (3, N)
        K1 = torch.stack([gvc, shift_nodes(gvc, -1), shift_nodes(gvc, -2)], 1)  # (3, k, N)
        K2 = torch.stack([K1, shift_nodes(K1, -S1), shift_nodes(K1, -2 * S1)], 1)  # (3, j, k, N)
        H = torch.stack([K2, shift_nodes(K2, -S0), shift_nodes(K2, -2 * S0)], 1)  # (3, i, j, k, N)
        H = H.reshape(81, n_nodes)
        if chunk >= P:
            vg = H.index_select(1, lin).view(3, 27, P) * w  # (3, 27, P)
            S = torch.matmul(o_aug_t.T, vg)  # (3, 4, P): [sum w v_i, sum w v_i o^T]
        else:
            S = torch.empty(3, 4, P, dtype=dtype, device=device)
            for s0 in range(0, P, chunk):
                sl = slice(s0, s0 + chunk)
                vg = H.index_select(1, lin[sl]).view(3, 27, -1).mul_(w[:, sl])
                torch.matmul(o_aug_t.T, vg, out=S[:, :, sl])
        v_pic = S[:, 0].T  # (P, 3)
        # paper eq. 9 (eq:particle_c), summing the grid velocities v'_i as in Hu et al. 2018 (the paper's v_p^(n+1)
        # inside the sum would make C vanish: sum_i w_ip (x_i - x_p) = 0)
        C_new = (4.0 * inv_dx) * (S[:, 1:].permute(2, 0, 1) - v_pic[:, :, None] * fx[:, None, :])
        if alpha is None:  # alpha = 1 everywhere: the hand velocity has no weight
            v_new = v_pic
        else:
            hv = torch.zeros(3, dtype=dtype, device=device) if hand_velocity is None else hand_velocity
            v_new = torch.addcmul((1.0 - alpha[:, None]) * hv, alpha[:, None], v_pic)  # paper eq. 8 (eq:particle_v)
        x_new = torch.add(x, v_new, alpha=dt)  # paper eq. 10 (eq:particle_x): x + dt v
        F_new = torch.add(F, matmul3(C_new, F), alpha=dt)  # paper eq. 11 (eq:particle_f): (I + dt C) F
        return replace(state, x=x_new, v=v_new, C=C_new, F=F_new)

    def last_particle_force(self, mass: Tensor, source: tuple[Transfer | None, Tensor | None] | None = None) -> Tensor:
        """The last step's collider force shared out over the particles that moved its nodes.

        Node i's force f_i (momentum the collider removed, / dt) goes to particle p in proportion to p's share of the
        node's mass, ``f_p = m_p sum_i w_ip f_i / m_i`` (the same B-spline weights as the transfer, so
        ``sum_p w_ip m_p = m_i`` and the particle forces of a scene sum to its ``last_force``).

        Args:
            mass: (P,) particle masses of the state passed to the last ``step``.
            source: an earlier step's :meth:`force_source` (None: the last step's).
        Returns:
            (P, 3) force on each particle (domain axes, simulation units), detached.
        """
        transfer, contact_force = self.force_source() if source is None else source
        if self.cfg.contact == "particle" and contact_force is not None:  # the colliders acted on the particles
            return contact_force  # their own forces (zero after a free-flight step, which has no transfer)
        if transfer is None:
            raise RuntimeError("last_particle_force needs a step first")
        ref = transfer.node_force
        o_int = self._constants(ref.dtype, ref.device)[2]
        if self._kernels is not None:  # compiled: one fused gather (same terms, compiled.step.particle_force)
            try:
                return particle_force(self._kernels, transfer, mass, o_int)
            except CompileFailed:
                self._kernels = None  # warned once; eager from now on
        return share_node_force(transfer, mass, o_int)

    def _speed_check(self, vmax: Tensor | None) -> None:
        """The grid speed check of a step (:func:`~tvrecon.sim.mpm.block_grid.check_grid_speed`) on ``vmax``, the 0-dim
        largest node velocity component (None: no node). With ``defer_checks`` the value is kept in
        ``pending_grid_speed`` for the caller's own host read (:meth:`check_pending`), a host sync fewer a step."""
        if self.defer_checks:
            self.pending_grid_speed = vmax if vmax is not None else torch.zeros((), device=self.device)
            return
        check_grid_speed(float(vmax) if vmax is not None else 0.0, self.dt, self.dx)

    def check_pending(self, vmax: float) -> None:
        """Run the deferred grid speed check of the last step on its value read by the caller
        (``float(pending_grid_speed)``). Raises FloatingPointError as the step itself would have."""
        check_grid_speed(vmax, self.dt, self.dx)

    def _chunk(self, P: int, device: torch.device) -> int:
        """Particles per chunk of the stencil passes: cache-sized blocks on the CPU without autograd, else all at once
        (a GPU streams them in one launch; chunks would cost launches in proportion to the batch)."""
        if torch.is_grad_enabled() or self.chunk_size <= 0 or device.type != "cpu":
            return P
        return self.chunk_size

    def _compiled_chunk(self, device: torch.device) -> int:
        """Particles per compiled P2G call: ``compiled_chunk_size`` on the CPU, all at once (0) elsewhere."""
        return self.compiled_chunk_size if device.type == "cpu" else 0
