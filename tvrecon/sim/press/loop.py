"""The press run: T placed touches stepped together in one MLS-MPM loop, each a small state machine.

Each touch (:class:`TouchRun`) goes ``approach -> press -> release -> done``:

- approach: the hand moves the pad towards the object at ``speed``; the first step with a normal contact force
  (> 0) enters ``press``. With the default ``gap`` of 1 cell the first step already touches.
- press: the hand keeps moving; after every step the stop rules (:mod:`tvrecon.sim.press.stop_rules`) are asked. A stop
  (from approach or press) takes the reading (image, force, chamfer).
- release (only with ``release_steps``): the hand retracts at ``speed`` as many steps as it pressed, then holds;
  after ``release_steps`` steps the reading gets its ``residual`` image.
- done: the touch leaves the batch (its particle block is dropped). Unreachable touches start here.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import warnings
from dataclasses import dataclass, field
from typing import NamedTuple

import torch
from torch import Tensor
from tqdm.auto import tqdm

from tvrecon.sim.mpm.compiled.policy import resolve_compile, touch_work
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import MPMConfig, ParticleState
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.press.placement import Placement, touch_z
from tvrecon.sim.press.reading import TactileReading
from tvrecon.sim.press.stop_rules import (
    StopCheck,
    ThresholdRule,
    criterion_missed,
    rest_sq_sums,
    rest_terms,
    should_stop,
    stop_rules,
    terminal_chamfer,
)
from tvrecon.sim.sensor.elastic_pad import SensorConfig, _scalar, alpha_profile, mass_scale, pad_lattice
from tvrecon.sim.sensor.forces import column_force_field

#: the press's steps before the pad meets the object are translations (``MLSMPM.free_flight``, :mod:`tvrecon.sim.mpm.
#: free_flight`: the pad starts at zero stress, moving with the hand, ``gap`` cells away); False: every step is a full
#: MLS-MPM step (the readings agree to float32 round-off)
FREE_FLIGHT = True


class Phase(enum.Enum):
    APPROACH = "approach"
    PRESS = "press"
    RELEASE = "release"
    DONE = "done"


@dataclass
class TouchRun:
    """One touch during the loop: its placement and where it is in ``approach -> press -> release -> done``."""

    place: Placement
    phase: Phase = Phase.APPROACH
    steps: int = 0  # approach + press steps
    release_left: int = 0
    retract_left: int = 0
    travel: float = 0.0  # hand travel along -z in cells (press minus retract)
    disp: Tensor | None = None  # (3,) differentiable hand displacement in domain units
    contact: bool = False  # the object pushed on the pad (entered `press`)
    force_hist: list[float] = field(default_factory=list)
    reading: TactileReading | None = None
    frames: list[Tensor] = field(default_factory=list)
    frame_steps: list[int] = field(default_factory=list)
    particles: list[Tensor] = field(default_factory=list)

    @property
    def pressing(self) -> bool:
        return self.phase in (Phase.APPROACH, Phase.PRESS)

    def hand_sign(self) -> float:
        """Hand velocity along the press axis this step, in units of ``speed``: +1 in, -1 out, 0 hold."""
        if self.pressing:
            return 1.0
        return -1.0 if self.retract_left > 0 else 0.0

    def felt(self, fz: float) -> None:
        """A press step with normal contact force ``fz``: count it; the first push moves approach -> press."""
        self.steps += 1
        self.force_hist.append(fz)
        if fz > 0:
            self.contact = True
            if self.phase is Phase.APPROACH:
                self.phase = Phase.PRESS

    def stop_pressing(self) -> None:
        """After the reading: release (retracting as many steps as pressed) or done."""
        if self.release_left > 0:
            self.phase = Phase.RELEASE
            self.retract_left = self.steps
        else:
            self.phase = Phase.DONE

    def released(self, sign: float) -> bool:
        """A release step moving the hand by ``sign``; True when the release is over."""
        self.release_left -= 1
        self.retract_left = max(self.retract_left - 1, 0) if sign < 0 else self.retract_left
        return self.release_left <= 0


#: block nodes per axis added over the first step's dims for the other steps of a window of unread steps
#: (``PressLoop.read_every``): the particles' stencils may spread this far before the window runs again with reads
WINDOW_MARGIN = 1


@dataclass
class _Go:
    """What every step of one loop iteration is run with (B scenes of P particles)."""

    solver: MLSMPM
    colliders: list
    hv: Tensor  # (3,) or (B * P, 3) hand velocity
    alpha: Tensor  # (B * P,) or (P,)
    moved: Tensor  # (B, 3) hand displacement per step
    B: int
    P: int
    rest: tuple[Tensor, float] | None  # the threshold rule's rest terms


@dataclass
class _Step:
    """One solver step of the loop and what its touches' stop checks read (references, no copies)."""

    n: int  # step number
    state: ParticleState | None  # after the step (None inside a window: only its last state is kept)
    disp: Tensor  # (B, 3) hand displacement after the step
    xb: Tensor  # (B, P, 3) positions
    contact_cells: Tensor  # (B, HW, 3) contact layers in cells
    force: Tensor  # (B, 3) pad forces
    bounds: Tensor | None  # (9,) the next step's block bounds, when the solver planned them
    had_list: bool  # the contact kept a candidate list (its drift is in the host values)
    force_source: tuple  # MLSMPM.force_source() of the step
    host_tensor: Tensor  # the values of the step's host read, on the device
    host: list[float] = field(default_factory=list)  # ... read


class PressLoop:
    """The shared solver loop over T placed touches (``EIPSimulator.press_batch`` builds and runs one).

    ``read_every`` (None: 4 on CUDA, 1 on the CPU): solver steps per host read. A read costs a GPU a stall every
    step; with more steps per read the touches that stop inside a window are stepped on to its end (their readings
    are those of their stop step, kept by reference) and the window is checked afterwards (:meth:`_window`)."""

    #: solver steps per host read (None: 4 on CUDA, where each read stalls the stream, 1 on the CPU)
    read_every: int | None = None

    def __init__(
        self,
        s: SensorConfig,
        p: PressConfig,
        mcfg: MPMConfig,
        speed,
        device: torch.device,
        compile: bool | str | None = None,
    ) -> None:
        self.s, self.p, self.mcfg, self.speed, self.device = s, p, mcfg, speed, device
        # MLSMPM(compile=...): fused no-grad steps, equal to round-off; None -> PressConfig.compile; "auto" is
        # resolved in run() with this call's touches (a lone press: eager; jobs resolve it for their process)
        self.compile = p.compile if compile is None else compile
        self.H, self.W = s.resolution
        self.HW, self.dx = self.H * self.W, 1.0 / int(p.n_grid)
        self.dt = float(mcfg.dt)
        self.step_cells = _scalar(speed) * self.dt / self.dx
        self.max_steps = (
            p.max_steps if p.max_steps is not None else math.ceil((float(p.gap) + float(p.max_depth)) / self.step_cells)
        )
        self.rules = stop_rules(p, self.max_steps)
        self.rewound = 0  # windows of unread steps run again with a read each step (a test counts them)
        self._k = max(1, int(self.read_every if self.read_every is not None else (4 if device.type == "cuda" else 1)))

    def run(self, places: list[Placement]) -> list[TactileReading]:
        s, p, dev, dx, dt, H, W, HW = self.s, self.p, self.device, self.dx, self.dt, self.H, self.W, self.HW
        speed = self.speed
        speed_t = torch.as_tensor(speed, dtype=torch.float32, device=dev)
        down = torch.tensor([0.0, 0.0, -1.0], device=dev)
        touches = [TouchRun(place=pl) for pl in places]

        lat = pad_lattice(s, device=dev)  # (P, 3) cells
        P = lat.shape[0]
        x_rest = lat * dx + torch.tensor([0.5, 0.5, touch_z(dx) + float(p.gap) * dx], device=dev)  # (P, 3) domain
        self.rest_contact = x_rest[:HW]
        alpha1 = alpha_profile(s, device=dev)  # (P,)
        vol = (float(s.spacing) * dx) ** 3
        zero_img = torch.zeros(3, H, W, dtype=torch.float32, device=dev)

        active = [t for t, tc in enumerate(touches) if tc.place.reachable]
        for tc in touches:
            if not tc.place.reachable:
                tc.reading = self._reading(tc, zero_img, chamfer=0.0, force=torch.zeros(3))
                tc.reading.contact = False
                tc.reading.force_field = torch.zeros(H, W, 3)
                tc.phase = Phase.DONE
        if not active:
            return [tc.reading for tc in touches]  # type: ignore[misc]

        for t in active:
            touches[t].release_left = int(p.release_steps)
        B = len(active)
        # each active touch's hand displacement so far (B, 3), one add per step for the batch; a touch's own row goes to
        # its TouchRun.disp where the image or the record reads it
        disp = torch.zeros(B, 3, device=dev, dtype=torch.float32)
        v0 = (speed_t * down).expand(B * P, 3)  # the pad starts moving rigidly with the hand: zero stress
        state = ParticleState.create(
            x_rest.repeat(B, 1),
            v0.clone() if not v0.requires_grad else v0 + 0.0,
            volume=torch.full((B * P,), vol, device=dev),
            rho=float(s.rho),
            batch=torch.arange(B, device=dev).repeat_interleave(P),
        )
        # the back layer is glued to the rigid, heavy mount (see SensorConfig.mount_mass)
        state = dataclasses.replace(state, mass=state.mass * mass_scale(s, device=dev).repeat(B))
        work = touch_work(P, int(p.n_grid))
        solver = MLSMPM(self.mcfg, device=dev, compile=resolve_compile(self.compile, len(places), dev, work=work)[0])
        solver.defer_checks = True  # its grid speed check rides on the step's one host read below
        solver.free_flight = FREE_FLIGHT  # the pad's approach with the hand: translated until it meets the body
        x0_contact = self.x0_contact = x_rest[:HW] / dx  # (HW, 3) cells
        lattice = (H, W, float(s.spacing))
        # the threshold rule's bound of every touch, read with the step's one host read (StopCheck.memo)
        rest = rest_terms(x0_contact, lattice) if any(isinstance(r, ThresholdRule) for r in self.rules) else None
        total = self.max_steps + int(p.release_steps)
        bar = tqdm(total=total * len(active), desc="EIP press", disable=not p.progress, leave=False)
        n = 0
        hands: dict[tuple[float, ...], Hand] = {}  # signs -> the hand's velocities and step (no autograd)
        while active:
            B = len(active)
            signs = [touches[t].hand_sign() for t in active]
            _, moved, hv, alpha = hands.get(tuple(signs)) or _hand(signs, speed_t, down, dt, alpha1, P, hands)
            colliders = [touches[t].place.collider for t in active]
            k = self._window_length(solver, state, hv, alpha, [touches[t] for t in active])
            go = _Go(solver, colliders, hv, alpha, moved, B, P, rest)
            steps = self._window(go, state, disp, n, k) if k > 1 else [self._one_step(go, state, disp, n + 1)]
            if n + len(steps) > total + 1:
                raise RuntimeError("press loop did not terminate (internal error)")
            n += len(steps)
            state, disp = steps[-1].state, steps[-1].disp
            assert state is not None
            done_now: list[int] = []
            for st in steps:
                self._replay(st, solver, state, touches, active, signs, done_now)
                bar.update(B - len(done_now))
            if done_now:
                keep_b = [b for b in range(B) if b not in done_now]
                for b in done_now:
                    _finish(touches[active[b]])
                active = [active[b] for b in keep_b]
                if active:
                    state = _select_blocks(state, keep_b, P)
                    disp = disp[keep_b]
        bar.close()
        return [tc.reading for tc in touches]  # type: ignore[misc]

    def _window_length(
        self, solver: MLSMPM, state: ParticleState, hv: Tensor, alpha: Tensor, runs: list[TouchRun]
    ) -> int:
        """Steps to run before the next host read: ``read_every`` (None: 4 on CUDA, 1 on the CPU) where the steps
        need no read between them (no autograd, no release, whose hand turns at a stop), and never past the step at
        which the last of ``runs`` reaches its travel limit (every pressing touch has pressed as many steps)."""
        k = self._k
        if k <= 1 or int(self.p.release_steps) > 0 or solver.needs_grad(state, hv, alpha):
            return 1
        return max(1, min(int(k), self.max_steps - max(tc.steps for tc in runs)))

    def _one_step(self, go: _Go, state: ParticleState, disp: Tensor, n: int) -> _Step:
        """One step and its host read (a free-flight step whose contact test failed redone as a real step, the polar's
        fixed steps redone iterating when they did not converge), the solver's deferred checks applied."""
        st = self._advance(go, state, disp, n)
        host = st.host_tensor.tolist()
        if host[4] == 0.0 and go.solver.flight.last:  # a free-flight step whose contact test failed: a real step
            go.solver.flight.end()
            st = self._advance(go, state, disp, n)
            host = st.host_tensor.tolist()
        if host[4] == 0.0:  # a particle's fixed-step polar did not converge: the step again, iterating to the end
            go.solver.exact_polar = True
            try:
                st = self._advance(go, state, disp, n)
                host = st.host_tensor.tolist()
            finally:
                go.solver.exact_polar = False
        st.host = host
        self._check(go, st, last=True)
        return st

    def _window(self, go: _Go, state: ParticleState, disp: Tensor, n: int, k: int) -> list[_Step]:
        """``k`` steps with one host read at the end (``read_every``): each step after the first gets its block dims
        with a margin of ``WINDOW_MARGIN`` nodes over the first's and reuses the contact's kept list. The read then
        checks what those steps took on trust (the blocks held every particle, no particle moved past the contact's
        skin, the fixed-step polar converged, the positions stayed finite); where one did not hold, the window runs
        again from its start with a read every step, so the result is the same as with ``read_every=1``."""
        solver = go.solver
        mark = solver.mark()
        steps: list[_Step] = []
        cur_state, cur_disp, dims = state, disp, None
        for j in range(k):
            st = self._advance(go, cur_state, cur_disp, n + j + 1)
            if steps:
                steps[-1].state = None  # only the window's last state goes on (its positions stay with xb)
            steps.append(st)
            cur_state, cur_disp = st.state, st.disp
            if j < k - 1:
                if dims is None and solver.last_dims is not None:
                    dims = [max(3, d + WINDOW_MARGIN) for d in solver.last_dims]
                solver.trust_next(dims or [0, 0, 0])
        hosts = torch.stack([st.host_tensor for st in steps]).tolist()  # the window's one host read
        for st, host in zip(steps, hosts, strict=True):
            st.host = host
        if all(self._held(go, st, dims) for st in steps[:-1]) and steps[-1].host[4] != 0.0:
            for j, st in enumerate(steps):
                self._check(go, st, last=j == k - 1)
            return steps
        solver.rewind(mark)
        self.rewound += 1
        out = []
        for j in range(k):
            out.append(self._one_step(go, state, disp, n + j + 1))
            state, disp = out[-1].state, out[-1].disp  # type: ignore[assignment]
        return out

    def _held(self, go: _Go, st: _Step, dims: list[int] | None) -> bool:
        """Whether the step after ``st`` (run without a read of ``st``) got what it took on trust."""
        h, B = st.host, go.B
        if not (math.isfinite(h[0]) and math.isfinite(h[1])) or h[4] == 0.0:
            return False
        if st.had_list and not h[3] <= go.solver.contact_skin_domain:  # also NaN
            return False
        if st.bounds is not None:
            ext = h[5 + B : 8 + B]
            if dims is None or not all(e <= d for e, d in zip(ext, dims, strict=True)):  # also NaN
                return False
        return True

    def _check(self, go: _Go, st: _Step, last: bool) -> None:
        """The solver's deferred checks of a step on its host values: grid speed and divergence (raise), and for the
        last step before the next one runs, the contact's drift and the next block dims."""
        solver, h = go.solver, st.host
        solver.check_pending(h[2])
        if not (math.isfinite(h[0]) and math.isfinite(h[1])):
            s, p = self.s, self.speed
            raise FloatingPointError(
                f"simulation diverged at step {st.n} (non-finite particle positions): lower PressConfig.dt or speed, "
                f"or raise damping; current dt={self.dt:.3g}, speed={_scalar(p):.3g}, E={_scalar(s.E):.3g}"
            )
        if last:
            if st.had_list:
                # a window that would outrun the kept list (the particles moving as fast as the fastest node) searches
                # at its first step instead of running again: the same contact, a search sooner, no steps twice
                trusted = (self._k - 1) * h[2] * self.dt
                solver.set_drift(h[3] if h[3] + trusted <= solver.contact_skin_domain else math.inf)
            if st.bounds is not None:
                solver.set_next_bounds(h[5 + go.B : 14 + go.B], go.B)

    def _replay(
        self,
        st: _Step,
        solver: MLSMPM,
        state: ParticleState,
        touches: list[TouchRun],
        active: list[int],
        signs: list[float],
        done_now: list[int],
    ) -> None:
        """Each active touch's state machine on one step's values (a touch that stopped at an earlier step of the
        window is past it); the touches done at this step are added to ``done_now``."""
        p, s, H, W, HW = self.p, self.s, self.H, self.W, self.HW
        x0_contact, lattice = self.x0_contact, (H, W, float(s.spacing))
        B = len(active)
        fz, rest_host = st.host[5 : 5 + B], st.host[5 + B :]
        sq_sums = rest_host[9:] if st.bounds is not None else rest_host
        particle_force = None  # (B, P, 3), computed on the first stop of this step
        for b, t in enumerate(active):
            tc = touches[t]
            if b in done_now:
                continue
            tc.disp = st.disp[b]  # a view: no launch
            tc.travel += signs[b] * self.step_cells
            if tc.pressing:
                tc.felt(fz[b])
                if p.record_every and tc.steps % int(p.record_every) == 0:
                    self._record(tc, st.xb[b])
                check = StopCheck(st.contact_cells[b], x0_contact, lattice)
                if sq_sums:
                    check.memo["rest_sq_sum"] = sq_sums[b]
                if should_stop(self.rules, tc, check):
                    img = self._image(st.xb[b, :HW], tc.disp)
                    # the threshold rule's exact value of this very layer, when it computed one (the same call)
                    ch = check.memo.get("chamfer")
                    if ch is None:
                        ch = terminal_chamfer(check.contact_cells, x0_contact, lattice)
                    f_world = tc.place.R @ st.force[b].cpu()
                    tc.reading = self._reading(tc, img, chamfer=ch, force=f_world)
                    if particle_force is None:
                        P = st.xb.shape[1]
                        particle_force = solver.last_particle_force(state.mass, st.force_source).view(B, P, 3)
                    tc.reading.force_field = column_force_field(particle_force[b], (H, W), int(s.layers)).float().cpu()
                    _warn_if_passed_through(tc, p)
                    if tc.contact and criterion_missed(self.rules, tc, check):
                        tc.reading.criterion_missed = True
                        _warn_criterion_missed(p)
                    if p.record_every and tc.steps % int(p.record_every) != 0:
                        self._record(tc, st.xb[b])
                    tc.stop_pressing()
            elif tc.phase is Phase.RELEASE:
                over = tc.released(signs[b])
                if p.record_every and (int(p.release_steps) - tc.release_left) % int(p.record_every) == 0:
                    self._record(tc, st.xb[b])
                if over:
                    assert tc.reading is not None
                    tc.reading.residual = self._image(st.xb[b, :HW], tc.disp)
                    tc.phase = Phase.DONE
            if tc.phase is Phase.DONE:
                done_now.append(b)

    def _advance(self, go: _Go, state: ParticleState, disp: Tensor, n: int) -> _Step:
        """Step ``n`` of the B scenes, and the values of its host read as one device vector (not read here): the
        contact layers' lowest and highest coordinate (divergence), the solver's grid speed, the particles' drift since
        the contact's kept search (NaN: none kept), whether the fixed-step polar converged (1.0 when not deferred) or
        a free-flight step's contact test held (``MLSMPM.free_flight``),
        the B normal forces (the stop rules), the 9 bounds of the next step's blocks when planned, then the threshold
        rule's sums when it runs."""
        solver, B, P = go.solver, go.B, go.P
        new = solver.step(state, collider=go.colliders, hand_velocity=go.hv, alpha=go.alpha)
        xb = new.x.view(B, P, 3)
        contact_cells = xb[:, : self.HW] / self.dx  # (B, HW, 3): every touch's contact layer in cells, one launch
        force = solver.last_force.detach()  # (B, 3) on the pad, domain axes
        lo_hi = torch.aminmax(xb[:, : self.HW].detach())  # NaN propagates: one reduction instead of isfinite + all
        assert solver.pending_grid_speed is not None
        vmax = solver.pending_grid_speed.to(lo_hi.min).reshape(())
        drift, ok = solver.pending_drift, solver.pending_polar_ok
        had_list = drift is not None
        drift = torch.full_like(vmax, math.nan) if drift is None else drift.to(vmax).reshape(())
        ok = torch.ones_like(vmax) if ok is None else ok.to(vmax).reshape(())
        bounds = solver.pending_bounds
        parts = [torch.stack([lo_hi.min, lo_hi.max, vmax, drift, ok]), force[:, 2]]
        if bounds is not None:
            parts.append(bounds)
        if go.rest is not None:
            parts.append(rest_sq_sums(contact_cells.detach(), go.rest))
        host = torch.cat([t.double() for t in parts])
        return _Step(n, new, disp + go.moved, xb, contact_cells, force, bounds, had_list, solver.force_source(), host)

    def _image(self, x_contact: Tensor, disp: Tensor, rest: Tensor | None = None) -> Tensor:
        """(HW, 3) domain positions -> (3, H, W) displacement in cells with the hand translation removed.

        ``rest``: (HW, 3) rest contact layer in domain units (default: the pad's)."""
        rest = self.rest_contact if rest is None else rest
        u = (x_contact - rest - disp) / self.dx  # (HW, 3); domain axes are the sensor axes
        return u.reshape(self.H, self.W, 3).permute(2, 0, 1).contiguous()

    def _to_world(self, tc: TouchRun, u: Tensor) -> Tensor:
        """(N, 3) domain -> (N, 3) world."""
        c = torch.tensor([0.5, 0.5, touch_z(self.dx)], dtype=u.dtype, device=u.device)
        R = tc.place.R.to(u.device)
        return tc.place.origin.to(u.device) + (u - c) * float(self.p.domain_size) @ R.T

    def _record(self, tc: TouchRun, x_pad: Tensor) -> None:
        tc.frames.append(self._image(x_pad[: self.HW].detach(), tc.disp.detach(), rest=self.x0_contact * self.dx))
        releasing = int(self.p.release_steps) - tc.release_left if tc.phase is Phase.RELEASE else 0
        tc.frame_steps.append(tc.steps + releasing)
        tc.particles.append(self._to_world(tc, x_pad.detach()).cpu())

    def _reading(self, tc: TouchRun, img: Tensor, chamfer: float, force: Tensor) -> TactileReading:
        p, dx = self.p, self.dx
        disp = tc.disp.detach().cpu() if tc.disp is not None else torch.zeros(3)
        centre = torch.tensor([0.5, 0.5, touch_z(dx) + float(p.gap) * dx]) + disp
        return TactileReading(
            image=img,
            position=self._to_world(tc, centre[None])[0].to(torch.float32),
            direction=tc.place.direction.clone(),
            steps=tc.steps,
            depth=max(0.0, tc.travel - float(p.gap)),
            chamfer=float(chamfer),
            force=force.to(torch.float32),
            contact=tc.contact,
            frame=tc.place.R.clone(),
            origin=tc.place.origin.clone(),
        )


class Hand(NamedTuple):
    """The hand of one set of active touches and phases (``_hand``)."""

    v_touch: Tensor  # (B, 3) hand velocity of each scene
    moved: Tensor  # (B, 3) its move in one step
    hv: Tensor  # the solver's hand velocity: (3,) for one scene without autograd (it broadcasts), else (B P, 3)
    alpha: Tensor  # the solver's alpha: (P,) or (B P,)


def _hand(
    signs: list[float],
    speed: Tensor,
    down: Tensor,
    dt: float,
    alpha1: Tensor,
    P: int,
    cache: dict[tuple[float, ...], Hand],
) -> Hand:
    """The hand of scenes whose ``signs`` are in units of ``speed`` along ``down``, with the pad's (P,) ``alpha1``;
    kept in ``cache`` under ``signs`` unless it needs gradients: the same tensors every step while the active touches
    and their phases stay, so no (B P, 3) expansion per step and the compiled step keeps its channel-first copy of the
    hand velocity (``MLSMPM._hand_cf``)."""
    v_touch = torch.tensor(signs, device=down.device)[:, None] * speed * down
    grad = v_touch.requires_grad or alpha1.requires_grad
    if len(signs) == 1 and not grad:  # the (3,) velocity broadcasts over the particles: no (P, 3) copy
        hv, alpha = v_touch[0], alpha1
    else:  # with autograd the gradients' summation order is kept as it was
        hv, alpha = v_touch.repeat_interleave(P, dim=0), alpha1.repeat(len(signs))
    out = Hand(v_touch, v_touch * dt, hv, alpha)
    if not grad:
        cache[tuple(signs)] = out
    return out


def _finish(tc: TouchRun) -> None:
    if tc.reading is None:
        return
    if tc.frames:
        tc.reading.frames = torch.stack(tc.frames)
        tc.reading.frame_steps = list(tc.frame_steps)
        tc.reading.particles = torch.stack(tc.particles)


def _warn_if_passed_through(tc: TouchRun, p: PressConfig) -> None:
    """Warn when the pad went a cell or more past the surface found under its footprint without feeling it.

    The rays of ``place_touch`` saw the object under the pad, so a press without contact means the grid did not
    resolve what the rays hit (a feature thinner than a cell between the nodes): not a clean miss.
    """
    past = tc.travel - float(p.gap)
    if tc.place.reachable and not tc.contact and past >= 1.0 - 1e-6:
        warnings.warn(
            f"the pad went {past:.2f} cells past the object's surface under its footprint (touch point "
            f"{[round(v, 4) for v in tc.place.origin.tolist()]}) without touching it: the object is thinner there "
            f"than the grid resolves. Raise n_grid or lower domain_size so the part spans several cells, or press "
            f"elsewhere",
            RuntimeWarning,
            stacklevel=5,
        )


def _warn_criterion_missed(p: PressConfig) -> None:
    """One warning per configuration (the text names no touch, so Python shows it once, not once per touch)."""
    asked = (
        f"depth {p.depth:g} cells"
        if p.depth is not None
        else f"force {_scalar(p.force):g}"
        if p.force is not None
        else f"threshold {_scalar(p.threshold):g}"
    )
    steps = f", max_steps {p.max_steps}" if p.max_steps is not None else ""
    warnings.warn(
        f"a press stopped at its travel limit (max_depth {float(p.max_depth):g} cells past the gap{steps}) before "
        f"its stop criterion ({asked}) was reached: its reading has criterion_missed=True. Ask for less, or raise "
        f"max_depth / max_steps",
        RuntimeWarning,
        stacklevel=5,
    )


def _select_blocks(state: ParticleState, keep: list[int], P: int) -> ParticleState:
    """Keep the particle blocks ``keep`` (each P particles) and renumber their batch index 0..len(keep)-1."""
    dev = state.x.device
    idx = (torch.tensor(keep, device=dev)[:, None] * P + torch.arange(P, device=dev)).reshape(-1)
    out = {}
    for f in dataclasses.fields(state):
        val = getattr(state, f.name)
        out[f.name] = (
            val[idx] if isinstance(val, Tensor) and val.ndim >= 1 and val.shape[0] == state.x.shape[0] else val
        )
    out["batch"] = torch.arange(len(keep), device=dev).repeat_interleave(P)
    return dataclasses.replace(state, **out)
