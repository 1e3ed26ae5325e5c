"""Depth at the physical stop across n_grid, one discretization changed at a time (issue 15 item 1).

The gear press of ``bench_physics.py`` section 4 (``scaled_pad``: the same physical pad at every n_grid) with
``contact="particle"`` and ``threshold_grid=128``; prints the stop depth per n_grid and its ratio to the finest.

    OMP_NUM_THREADS=1 python benchmarks/bench_stop_depth.py --grids 64 128 256                   # the default step
    OMP_NUM_THREADS=1 python benchmarks/bench_stop_depth.py --grids 64 128 256 --dt-factor 0.25  # 4x smaller step
    OMP_NUM_THREADS=1 python benchmarks/bench_stop_depth.py --grids 64 --dt-factor 0.25 --iterations 6 --spacing 0.25

``docs/physics.md`` ("Why n_grid 64 stops 18% deeper") has the numbers.
"""

from __future__ import annotations

import argparse
import time

from bench_physics import scaled_pad

from tvrecon.sim import particle_contact
from tvrecon.sim.mpm import MPMConfig, cfl_dt
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig


def pad(n_grid: int, spacing: float, thick_div: int) -> SensorConfig:
    """``scaled_pad`` with another particle spacing (cells) or thickness (1 / ``thick_div`` of the domain)."""
    if spacing == 0.5 and thick_div == 16:
        return scaled_pad(n_grid)
    f = int(round(0.5 / spacing))
    return SensorConfig(resolution=(n_grid // 2 * f,) * 2, layers=(n_grid // thick_div) * f + 1, spacing=spacing)


def main(argv: list[str] | None = None) -> int:
    from tvrecon.sim.__main__ import load_shape

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grids", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--dt-factor", type=float, default=1.0, help="time step / the CFL step")
    ap.add_argument("--iterations", type=int, default=particle_contact.ITERATIONS, help="contact passes per step")
    ap.add_argument("--spacing", type=float, default=0.5, help="particle spacing, cells")
    ap.add_argument("--thick-div", type=int, default=16, help="pad thickness = domain / this")
    args = ap.parse_args(argv)
    particle_contact.ITERATIONS = args.iterations  # read at every step

    mesh = load_shape("gear")
    direction = [0.0, 0.0, -1.0]
    pos = EIPSimulator(scaled_pad(128), PressConfig(n_grid=128)).touch_position(mesh, direction)
    rows = []
    for n in args.grids:
        s = pad(n, args.spacing, args.thick_div)
        dt = args.dt_factor * cfl_dt(MPMConfig(n_grid=n, E=s.E, nu=s.nu, rho=s.rho))
        t0 = time.process_time()
        r = EIPSimulator(s, PressConfig(n_grid=n, contact="particle", threshold_grid=128, dt=dt)).press(
            mesh, pos, direction
        )
        rows.append((n, r.depth, r.depth / n, r.steps, time.process_time() - t0))
    base = rows[-1][2]
    print(
        f"dt x {args.dt_factor:g}, {args.iterations} contact passes, spacing {args.spacing:g}, "
        f"pad 1/{args.thick_div} thick"
    )
    print("| n_grid | depth (cells) | depth (domain) | / finest | steps | CPU-s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for n, dc, dd, steps, cpu in rows:
        print(f"| {n} | {dc:.4f} | {dd:.5f} | {dd / base:.2f} | {steps} | {cpu:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
