"""Taichi CPU against our solver (eager and compiled) on the bench_sim scene, in one process.

Scene: ``benchmarks._common.press_scene`` (48 x 48 x 12 pad at half-cell spacing, n_grid 128, the sphere under the
pad, the back layer driven by the hand, CFL dt of ``MPMConfig()``: E 3, nu 0.25, rho 1, no friction, no damping),
``--steps`` steps. The Taichi side is a straightforward MLS-MPM kernel of the mpm3d / mpm128 family written here: P2G
with atomic adds into a dense ``n^3`` grid, fixed-corotated stress with ``R = U V^T`` from ``ti.svd``, a grid loop
(velocity, sphere collider projection, collider force), G2P with the hand blend of paper eq. 8; ``ti.cpu``, one thread
(``cpu_max_num_threads=1``). Three Taichi variants run: ``dense`` clears and updates all 128^3 nodes every step (the
textbook kernel); ``box`` only the nodes of a fixed box the pad can reach (its initial bounds, the hand's travel and a
margin: our solver also works on the particles' bounding block); ``box serial`` also serializes every loop
(``ti.loop_config(serialize=True)``; presumably Taichi then demotes the P2G atomic adds to plain adds, not checked in
the generated code): the fastest of the three on one thread, and the one to read the ratios against. Our solver runs
through its public contract, eager and ``compile=True``, torch on one thread.

Compile time is excluded (a warm-up run of each: 3 steps, all ``--steps`` for the compiled solver, whose grid kernel
recompiles once when the block strides first change); then ``--repeats`` rounds time all five, rotating which goes
first, and report particle-steps per CPU-second (``time.process_time``: every thread of the process) and, per round,
the ratios ours / Taichi; the medians over rounds are the result. The physics check compares the final states of the
last round with ``box serial``: max |x - x_taichi| over the particles (same order) in grid cells, the mean downward
displacement of the pad, and the collider force of the last step.

taichi is a benchmark-only extra, not a project dependency (benchmarks/speed/requirements-taichi.txt):

    pip install --target /tmp/ti-site --no-deps -r benchmarks/speed/requirements-taichi.txt
    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 PYTHONPATH=.:/tmp/ti-site \
        python -m benchmarks.speed.bench_taichi [--steps 200] [--repeats 3]
"""

import argparse  # no `from __future__ import annotations`: taichi reads the kernel annotations as objects
import statistics
import time

import numpy as np
import taichi as ti
import torch

from benchmarks._common import N_GRID, SPHERE_CENTER, SPHERE_RADIUS, press_scene
from tvrecon.sim.bodies.colliders import SphereCollider
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState
from tvrecon.sim.mpm.materials import lame_parameters


@ti.data_oriented
class TaichiMPM:
    """MLS-MPM on a dense ``n^3`` Taichi grid, one scene, float32 (see the module docstring).

    Args:
        n_particles: P.
        n_grid: cells across the unit domain.
        dt: time step.
        E, nu: Young's modulus and Poisson ratio.
        volume: particle volume V0 (mass = V0, rho 1).
    """

    def __init__(self, n_particles: int, n_grid: int, dt: float, E: float, nu: float, volume: float) -> None:
        self.n, self.dt = n_grid, dt
        self.x = ti.Vector.field(3, ti.f32, n_particles)
        self.v = ti.Vector.field(3, ti.f32, n_particles)
        self.C = ti.Matrix.field(3, 3, ti.f32, n_particles)
        self.F = ti.Matrix.field(3, 3, ti.f32, n_particles)
        self.alpha = ti.field(ti.f32, n_particles)
        self.grid_v = ti.Vector.field(3, ti.f32, (n_grid,) * 3)
        self.grid_m = ti.field(ti.f32, (n_grid,) * 3)
        self.force = ti.Vector.field(3, ti.f32, ())
        mu, lam = lame_parameters(E, nu)
        self.consts = (float(mu), float(lam), float(volume))

    def reset(self, x: np.ndarray, alpha: np.ndarray) -> None:
        """Rest state from (P, 3) positions and (P,) alpha; the whole grid zeroed."""
        self.x.from_numpy(x.astype(np.float32))
        self.alpha.from_numpy(alpha.astype(np.float32))
        self.v.fill(0.0)
        self.C.fill(0.0)
        self.F.from_numpy(np.broadcast_to(np.eye(3, dtype=np.float32), (x.shape[0], 3, 3)).copy())
        self.grid_v.fill(0.0)
        self.grid_m.fill(0.0)

    def run(self, steps: int, hand: tuple[float, ...], lo: tuple[int, ...], hi: tuple[int, ...], serial: bool) -> None:
        """``steps`` steps; the grid loops cover nodes ``lo <= I < hi`` (per axis); ``serial``: serialized loops."""
        mu, lam, vol = self.consts
        for _ in range(steps):
            self._step(self.dt, mu, lam, vol, ti.Vector(hand), ti.Vector(lo), ti.Vector(hi), serial)
        ti.sync()

    @ti.kernel
    def _step(
        self,
        dt: ti.f32,
        mu: ti.f32,
        lam: ti.f32,
        vol: ti.f32,
        hand: ti.types.vector(3, ti.f32),
        lo: ti.types.vector(3, ti.i32),
        hi: ti.types.vector(3, ti.i32),
        serial: ti.template(),
    ):
        n = self.n
        dx = 1.0 / n
        inv_dx = float(n)
        mass = vol
        c = ti.Vector(SPHERE_CENTER)
        ti.loop_config(serialize=serial)
        for i, j, k in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])):
            self.grid_v[i, j, k] = ti.Vector.zero(ti.f32, 3)
            self.grid_m[i, j, k] = 0.0
        ti.loop_config(serialize=serial)
        for p in range(self.x.shape[0]):  # P2G (paper eq. 5-6)
            base = ti.cast(self.x[p] * inv_dx - 0.5, ti.i32)
            fx = self.x[p] * inv_dx - ti.cast(base, ti.f32)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            F = self.F[p]
            U, sig, V = ti.svd(F)
            R = U @ V.transpose()
            J = F.determinant()
            P = 2.0 * mu * (F - R) + lam * (J - 1.0) * J * F.inverse().transpose()
            stress = -dt * vol * 4.0 * inv_dx * inv_dx * P @ F.transpose()
            affine = stress + mass * self.C[p]
            for a, b, d in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([a, b, d])
                dpos = (ti.cast(off, ti.f32) - fx) * dx
                weight = w[a][0] * w[b][1] * w[d][2]
                self.grid_v[base + off] += weight * (mass * self.v[p] + affine @ dpos)
                self.grid_m[base + off] += weight * mass
        self.force[None] = ti.Vector.zero(ti.f32, 3)
        ti.loop_config(serialize=serial)
        for i, j, k in ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])):  # grid (eq. 7) and the sphere
            m = self.grid_m[i, j, k]
            if m > 0:
                vi = self.grid_v[i, j, k] / m
                dpos = ti.Vector([i, j, k]) * dx - c
                dist = dpos.norm()
                nrm = dpos / dist
                vn = vi.dot(nrm)
                if dist - SPHERE_RADIUS < 0 and vn < 0:
                    new = vi - vn * nrm
                    self.force[None] += m * (new - vi) / dt
                    vi = new
                self.grid_v[i, j, k] = vi
        ti.loop_config(serialize=serial)
        for p in range(self.x.shape[0]):  # G2P (eq. 8-11)
            base = ti.cast(self.x[p] * inv_dx - 0.5, ti.i32)
            fx = self.x[p] * inv_dx - ti.cast(base, ti.f32)
            w = [0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2]
            new_v = ti.Vector.zero(ti.f32, 3)
            new_C = ti.Matrix.zero(ti.f32, 3, 3)
            for a, b, d in ti.static(ti.ndrange(3, 3, 3)):
                off = ti.Vector([a, b, d])
                dpos = (ti.cast(off, ti.f32) - fx) * dx
                weight = w[a][0] * w[b][1] * w[d][2]
                gv = self.grid_v[base + off]
                new_v += weight * gv
                new_C += 4.0 * inv_dx * inv_dx * weight * gv.outer_product(dpos)
            al = self.alpha[p]
            new_v = al * new_v + (1.0 - al) * hand
            self.v[p] = new_v
            self.C[p] = new_C
            self.x[p] += dt * new_v
            self.F[p] = (ti.Matrix.identity(ti.f32, 3) + dt * new_C) @ self.F[p]


def reach_box(x: torch.Tensor, hand: torch.Tensor, steps: int, dt: float, n: int) -> tuple[tuple[int, ...], ...]:
    """Node box (lo, hi) covering the pad's initial bounds, the hand's travel and a 4-cell margin, inside the grid."""
    travel = (hand.abs() * steps * dt * n).ceil().long()
    lo = ((x.amin(0) * n).floor().long() - 4 - travel).clamp(0, n)
    hi = ((x.amax(0) * n).ceil().long() + 5 + travel).clamp(0, n)
    return tuple(lo.tolist()), tuple(hi.tolist())


def run_ours(steps: int, compile: bool) -> tuple[float, ParticleState, torch.Tensor]:
    """CPU-s of ``steps`` steps of MLSMPM on the scene, the final state and the last (3,) collider force."""
    x, alpha, hand, vol = press_scene()
    solver = MLSMPM(MPMConfig(n_grid=N_GRID), compile=compile)
    state = ParticleState.create(x, None, volume=vol)
    col = SphereCollider(SPHERE_CENTER, SPHERE_RADIUS)
    c0 = time.process_time()
    for _ in range(steps):
        state = solver.step(state, collider=col, hand_velocity=hand, alpha=alpha)
    cpu = time.process_time() - c0
    if compile and not solver.compiled:
        raise RuntimeError("torch.compile failed: the compiled run fell back to eager (see the warning)")
    return cpu, state, solver.last_force[0]


def run_taichi(sim: TaichiMPM, steps: int, box: bool, serial: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """CPU-s of ``steps`` Taichi steps, the final (P, 3) x and the last (3,) force.

    ``box``: grid loops over ``reach_box`` only; ``serial``: every loop serialized (``ti.loop_config``), which lets
    Taichi turn the P2G atomic adds into plain adds (one thread either way)."""
    x, alpha, hand, _ = press_scene()
    lo, hi = reach_box(x, hand, steps, sim.dt, sim.n) if box else ((0, 0, 0), (sim.n,) * 3)
    sim.reset(x.numpy(), alpha.numpy())
    c0 = time.process_time()
    sim.run(steps, tuple(hand.tolist()), lo, hi, serial)
    return time.process_time() - c0, sim.x.to_numpy(), sim.force[None].to_numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    torch.set_num_threads(1)
    ti.init(arch=ti.cpu, cpu_max_num_threads=1, default_fp=ti.f32, default_ip=ti.i32, log_level=ti.WARN)
    x0, _, hand, vol = press_scene()
    P = x0.shape[0]
    cfg = MPMConfig(n_grid=N_GRID)
    dt = MLSMPM(cfg).dt
    sim = TaichiMPM(P, N_GRID, dt, float(cfg.E), float(cfg.nu), vol)
    box = reach_box(x0, hand, args.steps, dt, N_GRID)
    print(f"scene: P={P}, n_grid={N_GRID}, dt={dt:.4g}, steps={args.steps}, taichi box (lo, hi) {box}")
    runs = {
        "taichi dense": lambda n: run_taichi(sim, n, box=False, serial=False),
        "taichi box": lambda n: run_taichi(sim, n, box=True, serial=False),
        "taichi box serial": lambda n: run_taichi(sim, n, box=True, serial=True),
        "ours eager": lambda n: run_ours(n, compile=False),
        "ours compiled": lambda n: run_ours(n, compile=True),
    }
    names = tuple(runs)
    for k in names:  # JIT / torch.compile (and its one recompile when the block strides change), not timed
        t0, c0 = time.perf_counter(), time.process_time()
        n = args.steps if k == "ours compiled" else 3
        runs[k](n)
        print(
            f"warm-up {k} ({n} steps, compile included): {time.perf_counter() - t0:.1f} s wall, "
            f"{time.process_time() - c0:.1f} CPU-s"
        )
    cpu: dict[str, list[float]] = {k: [] for k in names}
    last = {}
    for r in range(args.repeats):
        order = names[r % len(names) :] + names[: r % len(names)]
        for k in order:
            last[k] = runs[k](args.steps)
            cpu[k].append(last[k][0])
        print(f"  round {r} (first: {order[0]}): " + ", ".join(f"{k} {cpu[k][-1]:.2f}" for k in names) + " CPU-s")
    for k in names:
        rate = [P * args.steps / c / 1e6 for c in cpu[k]]
        print(
            f"{k:>17}: median {statistics.median(rate):.3f} M particle-steps per CPU-s, runs "
            f"{[round(v, 3) for v in rate]}"
        )
    for ours in ("ours eager", "ours compiled"):
        for tk in names[:3]:
            ratios = [t / o for t, o in zip(cpu[tk], cpu[ours], strict=True)]
            print(
                f"{ours} / {tk}: median {statistics.median(ratios):.3f}x of {args.repeats} rounds "
                f"{[round(v, 3) for v in ratios]}"
            )
    x_init = x0.numpy()
    x_ti, f_ti = last["taichi box serial"][1], last["taichi box serial"][2]
    print(f"physics after {args.steps} steps, against taichi box serial (max over particles, in grid cells):")
    for k in ("taichi dense", "taichi box"):
        print(f"  {k}: max |dx| {np.abs(last[k][1] - x_ti).max() * N_GRID:.3g} cells")
    print(f"  taichi: mean z displacement {(x_ti - x_init)[:, 2].mean() * N_GRID:.4f} cells, force {f_ti.tolist()}")
    for ours in ("ours eager", "ours compiled"):
        xo, fo = last[ours][1].x.numpy(), last[ours][2].numpy()
        print(
            f"  {ours}: max |dx| {np.abs(xo - x_ti).max() * N_GRID:.3g} cells; mean z displacement "
            f"{(xo - x_init)[:, 2].mean() * N_GRID:.4f} cells; force {fo.tolist()} "
            f"(|df|/|f| {np.linalg.norm(fo - f_ti) / max(np.linalg.norm(f_ti), 1e-30):.3g})"
        )


if __name__ == "__main__":
    main()
