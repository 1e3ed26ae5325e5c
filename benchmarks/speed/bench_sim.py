"""Speed benchmark of the MLS-MPM solver on a press scene, against the straightforward reference port.

Scene: pad of 48 x 48 x 12 particles at half-cell spacing, 128 cells across the unit domain, a sphere collider under
the pad, the pad's back layer driven down by the hand (alpha = 0 there, 1 elsewhere: the "clamped" profile), 200
steps with the CFL time step. Runs ``tvrecon.sim.mpm.MLSMPM`` through its public contract and
``tvrecon.sim.mpm.reference`` (dense 128^3 grid, index_add_, torch.linalg.svd) in the same process, prints
particle-steps/s of both, their ratio, peak memory (max RSS) and the max abs difference of final positions.

    .venv/bin/python -m benchmarks.speed.bench_sim [--steps 200] [--repeats 2] [--threads N] [--skip-reference]

``--compile`` instead compares the eager step with ``MLSMPM(compile=True)`` (the fused ``torch.compile`` kernels)
in this one process: compile time (the first steps) reported apart, then ``--repeats`` timed runs of
each, alternating which goes first, and the eager / compiled ratio of particle-steps per CPU-second (the median of
the per-pair ratios: robust on a loaded machine), with the max |x, v, C, F| differences after ``--steps`` steps.
"""

from __future__ import annotations

import argparse
import resource
import time

import torch

from benchmarks._common import N_GRID, SPHERE_CENTER, SPHERE_RADIUS, press_scene
from tvrecon.sim.bodies.colliders import SphereCollider
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState
from tvrecon.sim.mpm.reference import ReferenceMPM


def run_ours(steps: int, compile: bool = False, full: bool = False):
    x, alpha, hand, vol = press_scene()
    solver = MLSMPM(MPMConfig(n_grid=N_GRID), compile=compile)
    state = ParticleState.create(x, None, volume=vol)
    col = SphereCollider(SPHERE_CENTER, SPHERE_RADIUS)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        state = solver.step(state, collider=col, hand_velocity=hand, alpha=alpha)
    if compile and not solver.compiled:
        raise RuntimeError("torch.compile failed: the compiled run fell back to eager (see the warning)")
    return time.perf_counter() - t0, time.process_time() - c0, state if full else state.x, solver.last_force[0]


def compare_compile(steps: int, repeats: int) -> None:
    """Eager vs ``MLSMPM(compile=True)`` in one process, interleaved (see the module docstring)."""
    P = 48 * 48 * 12
    run_ours(5)  # eager warm-up
    el, cpu, _, _ = run_ours(5, compile=True)  # compiles the four kernels (inductor's on-disk cache may help)
    print(f"compile: first 5 compiled steps took {el:.1f} s wall, {cpu:.1f} CPU-s (compile time, excluded below)")
    ratios, eager, comp = [], [], []
    for r in range(repeats):
        order = (False, True) if r % 2 == 0 else (True, False)
        res = {c: run_ours(steps, compile=c, full=True) for c in order}
        eager.append(res[False])
        comp.append(res[True])
        ratios.append(res[False][1] / res[True][1])
        print(
            f"  pair {r}: eager {res[False][1]:.2f} CPU-s, compiled {res[True][1]:.2f} CPU-s, "
            f"ratio {ratios[-1]:.3f} (first: {'compiled' if order[0] else 'eager'})"
        )
    ratios.sort()
    med = (
        ratios[len(ratios) // 2] if len(ratios) % 2 else 0.5 * (ratios[len(ratios) // 2 - 1] + ratios[len(ratios) // 2])
    )
    best_e, best_c = min(e[1] for e in eager), min(c[1] for c in comp)
    print(
        f"eager:    {P * steps / best_e / 1e6:.3f} M particle-steps per CPU-second (best of {repeats})\n"
        f"compiled: {P * steps / best_c / 1e6:.3f} M particle-steps per CPU-second (best of {repeats})\n"
        f"speed-up compiled / eager: median {med:.3f}x of {repeats} interleaved pairs, best/best {best_e / best_c:.3f}x"
    )
    se, sc = eager[-1][2], comp[-1][2]
    diffs = ", ".join(f"{n} {(getattr(sc, n) - getattr(se, n)).abs().max().item():.3g}" for n in ("x", "v", "C", "F"))
    print(
        f"after {steps} steps, max |compiled - eager|: {diffs}; force {comp[-1][3].tolist()} vs {eager[-1][3].tolist()}"
    )


def run_reference(steps: int, dt: float) -> tuple[float, float, torch.Tensor, torch.Tensor]:
    x, alpha, hand, vol = press_scene()
    P = x.shape[0]
    ref = ReferenceMPM(N_GRID, dt, E=3.0, nu=0.25)
    v = torch.zeros_like(x)
    C = torch.zeros(P, 3, 3)
    F = torch.eye(3).expand(P, 3, 3).clone()
    volume = torch.full((P,), vol)
    mass = volume.clone()
    col = SphereCollider(SPHERE_CENTER, SPHERE_RADIUS)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        x, v, C, F = ref.step(x, v, C, F, volume, mass, col, hand, alpha)
    return time.perf_counter() - t0, time.process_time() - c0, x, ref.last_force


def maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=2, help="timed runs of our solver (best is reported)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    ap.add_argument("--skip-reference", action="store_true")
    ap.add_argument("--compile", action="store_true", help="compare eager with MLSMPM(compile=True) instead")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    P = 48 * 48 * 12
    dt = MLSMPM(MPMConfig(n_grid=N_GRID)).dt
    print(
        f"scene: P={P} particles, n_grid={N_GRID}, dt={dt:.4g} (CFL), steps={args.steps}, "
        f"threads={torch.get_num_threads()}"
    )
    if args.compile:
        compare_compile(args.steps, args.repeats)
        return
    run_ours(5)  # warm-up
    runs = [run_ours(args.steps) for _ in range(args.repeats)]
    best = min(runs, key=lambda r: r[0])
    el, cpu, x_ours, f_ours = best
    rate, rate_cpu = P * args.steps / el, P * args.steps / cpu
    print(
        f"ours:      {rate / 1e6:.3f} M particle-steps/s wall ({rate_cpu / 1e6:.3f} M per CPU-second), "
        f"runs {[round(r[0], 2) for r in runs]} s, maxrss {maxrss_mb():.0f} MB, final force {f_ours.tolist()}"
    )
    if args.skip_reference:
        return
    el_ref, cpu_ref, x_ref, f_ref = run_reference(args.steps, dt)
    rate_ref, rate_ref_cpu = P * args.steps / el_ref, P * args.steps / cpu_ref
    print(
        f"reference: {rate_ref / 1e6:.3f} M particle-steps/s wall ({rate_ref_cpu / 1e6:.3f} M per CPU-second), "
        f"{el_ref:.2f} s, maxrss {maxrss_mb():.0f} MB, final force {f_ref.tolist()}"
    )
    diff = (x_ours - x_ref).abs().max().item()
    disp = (x_ref - press_scene()[0]).abs().max().item()
    print(f"speed-up ours / reference: {rate / rate_ref:.2f}x wall, {rate_cpu / rate_ref_cpu:.2f}x CPU time")
    print(
        f"final positions: max |ours - reference| = {diff:.3g} (= {diff * N_GRID:.3g} cells; max displacement "
        f"{disp * N_GRID:.3g} cells)"
    )


if __name__ == "__main__":
    main()
