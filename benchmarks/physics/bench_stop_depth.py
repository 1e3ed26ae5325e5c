"""Depth at the physical stop across n_grid, one discretization changed at a time.

The gear press of ``bench_physics.py`` section 4 (``scaled_pad``: the same physical pad at every n_grid) with
``contact="particle"`` and ``threshold_grid=128``; prints the stop depth per n_grid and its ratio to the finest, the
normal force at the stop, and the correlation of each stop image with the finest grid's (the finer image
average-pooled onto the coarser pixels, both in domain units; ``bench_physics.py`` section 4's method).

``--rule force`` stops the same press with ``PressConfig.force`` instead (the normal contact force, mean of the last
3 steps, reaches ``--force``). ``MLSMPM.last_force`` is in domain units at every n_grid (particle mass ``rho *
(spacing * dx)^3`` with ``dx = 1 / n_grid``, velocities in domains / s, ``dt`` in s), so one ``--force`` is one
physical force at every grid (the threshold rule's stops at 128 and 256, 0.00273 and 0.00266 deep, feel 1.271e-2
and 1.250e-2). At the default 0.1 c_p the force at first contact is an impact peak (1.6e-2 to 2.1e-2) followed by
a plateau near 1.25e-2, so a force at the threshold stop's (0.0127) stops at the third step in contact at every
grid; the default 0.03 is above both.
``--contact grid`` presses with the grid contact (the former default); ``--speed-fraction``
sets the hand speed (default 0.1 c_p). ``--shapes`` presses other objects of the library (``tvrecon.data.shapes``,
or ``sphere``) the same way, from the top at their ``touch_position``, and ends with one summary row per shape;
``all`` is the whole library. A press that reaches its travel limit before the rule is marked ``travel``.
``--terminal displacement`` stops on the particle-matched displacement instead of eq. 12 (``PressConfig.terminal``).

    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256  # the default step
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256 --dt-factor 0.25  # 4x smaller
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 --dt-factor 0.25 \\
        --iterations 6 --spacing 0.25
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256 --rule force      # a force stop
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256 --contact grid    # grid contact
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256 --speed-fraction 0.03 \\
        --rule force --force 0.0098                                                              # a slower press
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_depth --grids 64 128 256 --shapes sphere ball egg

``docs/notes/stop-depth.md`` explains what the stops across grids show.
"""

from __future__ import annotations

import argparse
import time

import torch
import trimesh

from benchmarks.physics.bench_physics import _corr, scaled_pad
from tvrecon.data.shapes import available_classes, make_shape
from tvrecon.sim.mpm import MPMConfig, cfl_dt, particle_contact
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.config import TERMINAL_MEASURES
from tvrecon.sim.sensor import SensorConfig

#: ``--rule force`` default: normal contact force at the stop, domain units (see the module docstring)
FORCE = 0.03


def pad(n_grid: int, spacing: float, thick_div: int) -> SensorConfig:
    """``scaled_pad`` with another particle spacing (cells) or thickness (1 / ``thick_div`` of the domain)."""
    if spacing == 0.5 and thick_div == 16:
        return scaled_pad(n_grid)
    f = int(round(0.5 / spacing))
    return SensorConfig(resolution=(n_grid // 2 * f,) * 2, layers=(n_grid // thick_div) * f + 1, spacing=spacing)


def pooled_corr(coarse: torch.Tensor, fine: torch.Tensor) -> tuple[float, float]:
    """(normal, shear) correlation of two (3, H, W) images in domain units, ``fine`` average-pooled onto ``coarse``."""
    k = fine.shape[-1] // coarse.shape[-1]
    f = torch.nn.functional.avg_pool2d(fine[None], k)[0] if k > 1 else fine
    return _corr(coarse[2], f[2]), _corr(coarse[:2], f[:2])


def shape_mesh(name: str) -> trimesh.Trimesh:
    """An object of the library (``tvrecon.data.shapes``, seed 0) or a CLI built-in (``sphere``: an icosphere)."""
    from tvrecon.sim.__main__ import load_shape

    return make_shape(name, seed=0) if name in available_classes() else load_shape(name)


def press_grids(args: argparse.Namespace, name: str) -> list[tuple]:
    """Press ``name`` from the top at every ``args.grids``; one row per grid (see :func:`main`)."""
    mesh = shape_mesh(name)
    direction = [0.0, 0.0, -1.0]
    pos = EIPSimulator(scaled_pad(128), PressConfig(n_grid=128)).touch_position(mesh, direction)
    stop = {"threshold_grid": 128, "terminal": args.terminal} if args.rule == "threshold" else {"force": args.force}
    rows = []
    for n in args.grids:
        s = pad(n, args.spacing, args.thick_div)
        dt = args.dt_factor * cfl_dt(MPMConfig(n_grid=n, E=s.E, nu=s.nu, rho=s.rho))
        p = PressConfig(n_grid=n, contact=args.contact, dt=dt, speed_fraction=args.speed_fraction, **stop)
        t0 = time.process_time()
        r = EIPSimulator(s, p).press(mesh, pos, direction)
        fn = float(-(r.force.double() @ torch.tensor(direction, dtype=torch.float64)))  # normal force on the pad
        travel = r.depth >= float(p.max_depth) - 1e-3  # the travel limit stopped it, not the rule
        rows.append((n, r.depth, r.depth / n, fn, r.image / n, r.steps, time.process_time() - t0, travel))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grids", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--dt-factor", type=float, default=1.0, help="time step / the CFL step")
    ap.add_argument("--iterations", type=int, default=particle_contact.ITERATIONS, help="contact passes per step")
    ap.add_argument("--spacing", type=float, default=0.5, help="particle spacing, cells")
    ap.add_argument("--thick-div", type=int, default=16, help="pad thickness = domain / this")
    ap.add_argument("--contact", choices=("particle", "grid"), default="particle")
    ap.add_argument("--rule", choices=("threshold", "force"), default="threshold", help="the stop rule")
    ap.add_argument("--force", type=float, default=FORCE, help="--rule force: normal force at the stop, domain units")
    ap.add_argument("--speed-fraction", type=float, default=0.1, help="hand speed / the P-wave speed")
    ap.add_argument("--shapes", nargs="+", default=["gear"], help="objects to press (library names, sphere, or all)")
    ap.add_argument("--terminal", choices=TERMINAL_MEASURES, default="chamfer", help="what the threshold measures")
    args = ap.parse_args(argv)
    particle_contact.ITERATIONS = args.iterations  # read at every step

    summary = []
    for name in available_classes() if args.shapes == ["all"] else args.shapes:
        rows = press_grids(args, name)
        summary.append((name, rows))
        print_rows(args, name, rows)
    if len(summary) > 1:
        print_summary(args, summary)
    return 0


def print_rows(args: argparse.Namespace, name: str, rows: list[tuple]) -> None:
    """One shape's table: depth, ratio to the finest grid, force, image correlation with the finest grid."""
    base, img_f = rows[-1][2], rows[-1][4]
    print(
        f"{name}: {args.contact} contact, stop: {args.rule} "
        f"({f'threshold_grid 128, {args.terminal}' if args.rule == 'threshold' else f'force {args.force:g}'}), "
        f"dt x {args.dt_factor:g}, "
        f"{args.iterations} contact passes, spacing {args.spacing:g}, pad 1/{args.thick_div} thick, "
        f"speed {args.speed_fraction:g} c_p"
    )
    print(
        "| n_grid | depth (cells) | depth (domain) | / finest | normal force, last step | normal corr. | shear corr. "
        "| steps | CPU-s |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for n, dc, dd, fn, img, steps, cpu, travel in rows:
        cn, cs = pooled_corr(img, img_f) if n != rows[-1][0] else (1.0, 1.0)
        rel = dd / base if base > 0 else float("nan")
        print(
            f"| {n} | {dc:.4f}{' travel' if travel else ''} | {dd:.5f} | {rel:.2f} | {fn:.3e} | {cn:.3f} | {cs:.3f} "
            f"| {steps} | {cpu:.1f} |"
        )


def print_summary(args: argparse.Namespace, summary: list[tuple[str, list[tuple]]]) -> None:
    """One row per shape: stop depth (domain units) per grid and its ratio to the finest grid."""
    grids = args.grids
    print(
        "\n| shape | "
        + " | ".join(f"depth {n}" for n in grids)
        + " | "
        + " | ".join(f"{n} / {grids[-1]}" for n in grids[:-1])
        + " |"
    )
    print("| --- " * (2 * len(grids)) + "|")
    for name, rows in summary:
        base = rows[-1][2]
        depths = " | ".join(f"{r[2]:.5f}{' (travel)' if r[7] else ''}" for r in rows)
        ratios = " | ".join(f"{r[2] / base:.2f}" if base > 0 else "nan" for r in rows[:-1])
        print(f"| {name} | {depths} | {ratios} |")


if __name__ == "__main__":
    raise SystemExit(main())
