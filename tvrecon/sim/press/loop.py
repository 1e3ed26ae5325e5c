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
from tvrecon.sim.sensor.forces import column_force_field
from tvrecon.sim.sensor.pad import SensorConfig, _scalar, alpha_profile, mass_scale, pad_lattice


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


class PressLoop:
    """The shared solver loop over T placed touches (``EIPSimulator.press_batch`` builds and runs one)."""

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
        x0_contact = self.x0_contact = x_rest[:HW] / dx  # (HW, 3) cells
        lattice = (H, W, float(s.spacing))
        # the threshold rule's bound of every touch, read with the step's one host read (StopCheck.memo)
        rest = rest_terms(x0_contact, lattice) if any(isinstance(r, ThresholdRule) for r in self.rules) else None
        total = self.max_steps + int(p.release_steps)
        bar = tqdm(total=total * len(active), desc="EIP press", disable=not p.progress, leave=False)
        n = 0
        hands: dict[tuple[float, ...], tuple[Tensor, Tensor]] = {}  # signs -> hand velocity and step (no autograd)
        while active:
            n += 1
            if n > total + 1:
                raise RuntimeError("press loop did not terminate (internal error)")
            B = len(active)
            signs = [touches[t].hand_sign() for t in active]
            v_touch, moved = hands.get(tuple(signs)) or _hand(signs, speed_t, down, dt, hands)  # (B, 3) each
            # one scene without autograd: the (3,) hand velocity broadcasts over the particles (the same values, no
            # (P, 3) copy per step; with autograd the gradients' summation order is kept as it was)
            one = B == 1 and not (v_touch.requires_grad or alpha1.requires_grad)
            hv = v_touch[0] if one else v_touch.repeat_interleave(P, dim=0)  # (3,) or (B * P, 3)
            alpha = alpha1 if one else alpha1.repeat(B)
            colliders = [touches[t].place.collider for t in active]
            new, xb, contact_cells, force, bounds, host = self._advance(solver, state, colliders, hv, alpha, B, P, rest)
            if host[4] == 0.0:  # a particle's fixed-step polar did not converge: the step again, iterating to the end
                solver.exact_polar = True
                try:
                    new, xb, contact_cells, force, bounds, host = self._advance(
                        solver, state, colliders, hv, alpha, B, P, rest
                    )
                finally:
                    solver.exact_polar = False
            state = new
            disp = disp + moved
            solver.check_pending(host[2])
            if solver.pending_drift is not None:
                solver.set_drift(host[3])
            fz, rest_host = host[5 : 5 + B], host[5 + B :]
            next_bounds, sq_sums = (rest_host[:9], rest_host[9:]) if bounds is not None else (None, rest_host)
            if not (math.isfinite(host[0]) and math.isfinite(host[1])):
                raise FloatingPointError(
                    f"simulation diverged at step {n} (non-finite particle positions): lower PressConfig.dt or speed, "
                    f"or raise damping; current dt={dt:.3g}, speed={_scalar(speed):.3g}, E={_scalar(s.E):.3g}"
                )
            if next_bounds is not None:
                solver.set_next_bounds(next_bounds, B)
            particle_force = None  # (B, P, 3), computed on the first stop of this step
            done_now = []
            for b, t in enumerate(active):
                tc = touches[t]
                tc.disp = disp[b]  # a view: no launch
                tc.travel += signs[b] * self.step_cells
                if tc.pressing:
                    tc.felt(fz[b])
                    if p.record_every and tc.steps % int(p.record_every) == 0:
                        self._record(tc, xb[b])
                    check = StopCheck(contact_cells[b], x0_contact, lattice)
                    if sq_sums:
                        check.memo["rest_sq_sum"] = sq_sums[b]
                    if should_stop(self.rules, tc, check):
                        img = self._image(xb[b, :HW], tc.disp)
                        # the threshold rule's exact value of this very layer, when it computed one (the same call)
                        ch = check.memo.get("chamfer")
                        if ch is None:
                            ch = terminal_chamfer(check.contact_cells, x0_contact, lattice)
                        f_world = tc.place.R @ force[b].cpu()
                        tc.reading = self._reading(tc, img, chamfer=ch, force=f_world)
                        if particle_force is None:
                            particle_force = solver.last_particle_force(state.mass).view(B, P, 3)
                        tc.reading.force_field = (
                            column_force_field(particle_force[b], (H, W), int(s.layers)).float().cpu()
                        )
                        _warn_if_passed_through(tc, p)
                        if tc.contact and criterion_missed(self.rules, tc, check):
                            tc.reading.criterion_missed = True
                            _warn_criterion_missed(p)
                        if p.record_every and tc.steps % int(p.record_every) != 0:
                            self._record(tc, xb[b])
                        tc.stop_pressing()
                elif tc.phase is Phase.RELEASE:
                    over = tc.released(signs[b])
                    if p.record_every and (int(p.release_steps) - tc.release_left) % int(p.record_every) == 0:
                        self._record(tc, xb[b])
                    if over:
                        assert tc.reading is not None
                        tc.reading.residual = self._image(xb[b, :HW], tc.disp)
                        tc.phase = Phase.DONE
                if tc.phase is Phase.DONE:
                    done_now.append(b)
            bar.update(B)
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

    def _advance(
        self,
        solver: MLSMPM,
        state: ParticleState,
        colliders: list,
        hv: Tensor,
        alpha: Tensor,
        B: int,
        P: int,
        rest: tuple[Tensor, float] | None,
    ) -> tuple[ParticleState, Tensor, Tensor, Tensor, Tensor | None, list[float]]:
        """One solver step of the B scenes and the step's one host read.

        Returns the new state, its (B, P, 3) positions and (B, HW, 3) contact layers in cells, the (B, 3) pad forces,
        the next step's block bounds (or None) and the host values: the contact layers' lowest and highest
        coordinate (divergence), the solver's grid speed, the particles' drift since the contact's kept search (NaN:
        none kept), whether the fixed-step polar converged (1.0 when not deferred), the B normal forces (the stop
        rules), the 9 bounds when planned, then the threshold rule's sums when it runs."""
        state = solver.step(state, collider=colliders, hand_velocity=hv, alpha=alpha)
        xb = state.x.view(B, P, 3)
        contact_cells = xb[:, : self.HW] / self.dx  # (B, HW, 3): every touch's contact layer in cells, one launch
        force = solver.last_force.detach()  # (B, 3) on the pad, domain axes
        lo_hi = torch.aminmax(xb[:, : self.HW].detach())  # NaN propagates: one reduction instead of isfinite + all
        # one host read per step: the positions' range (divergence), the pad forces (the stop rules), the solver's
        # grid speed check, its deferred polar test and the contact's drift, and the next step's block bounds (the
        # eager solver plans them; None from the compiled one)
        assert solver.pending_grid_speed is not None
        vmax = solver.pending_grid_speed.to(lo_hi.min).reshape(())
        drift, ok = solver.pending_drift, solver.pending_polar_ok
        drift = torch.full_like(vmax, math.nan) if drift is None else drift.to(vmax).reshape(())
        ok = torch.ones_like(vmax) if ok is None else ok.to(vmax).reshape(())
        bounds = solver.pending_bounds
        parts = [torch.stack([lo_hi.min, lo_hi.max, vmax, drift, ok]), force[:, 2]]
        if bounds is not None:
            parts.append(bounds)
        if rest is not None:
            parts.append(rest_sq_sums(contact_cells.detach(), rest))
        host = torch.cat([t.double() for t in parts]).tolist()
        return state, xb, contact_cells, force, bounds, host

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


def _hand(
    signs: list[float], speed: Tensor, down: Tensor, dt: float, cache: dict[tuple[float, ...], tuple[Tensor, Tensor]]
) -> tuple[Tensor, Tensor]:
    """(B, 3) hand velocity of each scene (``signs`` in units of ``speed`` along ``down``) and its (B, 3) move in one
    step of ``dt``; kept in ``cache`` under ``signs`` unless it needs gradients (the same values every step)."""
    v_touch = torch.tensor(signs, device=down.device)[:, None] * speed * down
    out = v_touch, v_touch * dt
    if not v_touch.requires_grad:
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
