"""Quasi-static Hertz check (issue 15 item 1): the sphere press of ``bench_physics.py`` section 1 read at rest.

The hand stops at a few depths and holds while the grid velocities are damped (dynamic relaxation,
:mod:`quasi_static`); force and contact radius are the means over the end of each hold, as an indentation
test reads them. The exponents are log-log fits over the hold depths; the ratios are taken at the hold ``d_cmp``.

    OMP_NUM_THREADS=1 python benchmarks/bench_hertz_static.py --size small --out outputs/bench_hertz_static
    OMP_NUM_THREADS=1 python benchmarks/bench_hertz_static.py --size issue --offsets 0.25   # one offset, ~4 CPU-min
    OMP_NUM_THREADS=1 python benchmarks/bench_hertz_static.py --size issue --contact grid --offsets 0.25 --out DIR
    OMP_NUM_THREADS=1 python benchmarks/bench_hertz_static.py --size tiny --out /tmp/bhs      # smoke run

``--out`` gets the table (``hertz_static.md``), ``hertz_static.json``, the plot and the per-step traces
(``hertz_static_traces.npz``: offsets, depth, force, radius, hold), from which one-offset runs can be plotted
together::

    python benchmarks/bench_hertz_static.py --combine DIR0 DIR1 DIR2 DIR3 --out DIR   # the table and plot of them all

``docs/physics.md`` (section "Why 0.1 c_p misses Hertz, and the reading at rest") has the numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "sim"))  # the physics checks live with the tests
from tvrecon.sim.validation.physics_checks import (
    SlabPress,
    draw_contact_theory,
    hertz_force,
    hertz_radius,
    label_contact_axes,
    slab_press,
    winkler_force,
    winkler_radius,
)
from tvrecon.sim.validation.quasi_static import hold_means

OFFSETS = (0.0, 0.25, 0.5, 0.75)
E0, NU0 = 3.0, 0.25

#: scenes (lengths in cells); ``holds`` end at ``max_depth``; ``d_cmp`` is one of them
SIZES = {
    "tiny": {"scene": {"n_grid": 32, "width": 12.0, "thick": 3.0, "R": 6.0}, "holds": (0.5, 1.0, 1.5), "d_cmp": 1.0},
    "small": {  # bench_physics.py --size small, section 1
        "scene": {"n_grid": 128, "width": 32.0, "thick": 6.0, "R": 12.0},
        "holds": (0.75, 1.25, 2.0, 3.0),
        "d_cmp": 2.0,
    },
    "issue": {  # the R and h at n_grid 256; 48 cells wide (the thin-layer a is 16 cells at d = 4)
        "scene": {"n_grid": 256, "width": 48.0, "thick": 12.0, "R": 32.0},
        "holds": (0.75, 1.5, 2.67, 4.0),
        "d_cmp": 2.67,
    },
}


def rows(r: SlabPress, holds: tuple[float, ...], d_cmp: float) -> list[dict]:
    """Static exponents and ratios per offset of a step-and-hold :func:`slab_press`."""
    assert r.hold is not None
    hd, hf, ha, har = hold_means(r.hold, r.depth, r.force, r.radius, r.area_radius)
    k = holds.index(d_cmp)
    R, h, dx = r.R, r.thick, r.dx
    out = []
    for b, off in enumerate(r.offsets):
        last = [np.flatnonzero(r.hold[b] == j) for j in range(len(holds))]
        tails = [r.force[b, s[len(s) // 2 :]] for s in last]
        arrive = int(last[0][0]) - 1  # the step that reaches the first hold: a constant-speed press up to there
        d = hd[b]
        out.append(
            {
                "offset": off,
                "depths": d.tolist(),
                "force": hf[b].tolist(),
                "a_holds": ha[b].tolist(),
                "force_exponent": float(np.polyfit(np.log(d), np.log(hf[b]), 1)[0]),
                "radius_exponent": float(np.polyfit(np.log(d), np.log(ha[b]), 1)[0]),
                "area_radius_exponent": float(np.polyfit(np.log(d), np.log(har[b]), 1)[0]),
                "a": float(ha[b, k]),
                "F/F_hertz": float(hf[b, k] / hertz_force(E0, NU0, R * dx, d[k] * dx)),
                "F/F_winkler": float(hf[b, k] / winkler_force(E0, NU0, R * dx, h * dx, d[k] * dx)),
                "settle_std": float(max(t.std() / abs(t.mean()) for t in tails)),
                "moving/static_first_hold": float(r.force[b, arrive] / hf[b, 0]),
            }
        )
    return out


def table(res: dict) -> str:
    c, d = res["scene"], res["d_cmp"]
    L = [
        f"Quasi-static Hertz, {res['contact']} contact: sphere R={c['R']:g} cells into a {c['width']:g}-cell pad "
        f"{c['thick']:g} cells thick (n_grid {c['n_grid']}), holds at {list(res['holds'])} cells "
        f"({res['hold_steps']} steps each, damped), ratios at d={d:g}",
        "| apex offset (cell) | force exponent | radius exponent | area-radius exponent | a (cells) | F / F_Hertz | "
        "F / F_thin-layer | hold std / mean | moving / static at the first hold |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in res["rows"]:
        L.append(
            f"| {r['offset']:g} | {r['force_exponent']:.2f} | {r['radius_exponent']:.2f} | "
            f"{r['area_radius_exponent']:.2f} | {r['a']:.2f} | {r['F/F_hertz']:.2f} | {r['F/F_winkler']:.2f} | "
            f"{r['settle_std']:.3f} | {r['moving/static_first_hold']:.2f} |"
        )
    L.append(
        f"\nTheory at d={d:g}: Hertz a = {float(hertz_radius(c['R'], d)):.2f}, thin layer a = "
        f"{float(winkler_radius(c['R'], d)):.2f} cells. {res['particles']} particles, {res['steps']} steps, "
        f"{res['cpu_s']:.1f} CPU-s"
    )
    return "\n".join(L)


def plot(r: SlabPress, res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    R, dx, h = r.R, r.dx, r.thick
    unit = E0 / (1 - NU0**2) * dx**2  # forces as F / (E* dx^2)
    dd = np.linspace(0.05, float(np.nanmax(r.depth)), 200)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for b, row in enumerate(res["rows"]):
        m = r.depth[b] > 0.05
        ax[0].loglog(r.depth[b][m], r.force[b][m] / unit, lw=0.6, alpha=0.5)
        ax[0].loglog(row["depths"], np.array(row["force"]) / unit, "o", label=f"at rest, apex +{row['offset']:g}")
        ax[1].plot(r.depth[b], r.radius[b], lw=0.6, alpha=0.5)
        ax[1].plot(row["depths"], row["a_holds"], "o")
    draw_contact_theory(ax, E0, NU0, R, h, dx, dd)
    label_contact_axes(ax, "force: every step (lines), at rest (dots)", radius_xmin=-0.2)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def combine(dirs: list[Path], out: Path) -> None:
    """The table and plot of several ``--out`` folders (one-offset runs of one scene) together, into ``out``."""
    runs = [(json.loads((d / "hertz_static.json").read_text()), np.load(d / "hertz_static_traces.npz")) for d in dirs]
    S = max(t["depth"].shape[1] for _, t in runs)

    def stack(key: str, fill: float) -> np.ndarray:  # runs of different step counts, padded
        return np.concatenate(
            [np.pad(t[key], ((0, 0), (0, S - t[key].shape[1])), constant_values=fill) for _, t in runs]
        )

    res = dict(runs[0][0])
    res["rows"] = [row for r, _ in runs for row in r["rows"]]
    res["particles"] = sum(r["particles"] for r, _ in runs)
    res["steps"] = max(r["steps"] for r, _ in runs)
    res["cpu_s"] = sum(r["cpu_s"] for r, _ in runs)
    c = res["scene"]
    r = SlabPress(
        depth=stack("depth", np.nan),
        force=stack("force", np.nan),
        radius=stack("radius", np.nan),
        area_radius=stack("radius", np.nan),  # not plotted
        offsets=[o for _, t in runs for o in t["offsets"].tolist()],
        dx=1.0 / c["n_grid"],
        E=E0,
        nu=NU0,
        R=c["R"],
        thick=c["thick"],
        particles=res["particles"],
        steps=res["steps"],
        hold=stack("hold", -1),
    )
    text = table(res) + f" (sums over {len(runs)} runs)"
    print(text)
    out.mkdir(parents=True, exist_ok=True)
    (out / "hertz_static.md").write_text(text + "\n")
    plot(r, res, out / "hertz_static.png")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", choices=sorted(SIZES), default="small")
    ap.add_argument("--offsets", type=float, nargs="+", default=list(OFFSETS), help="apex offsets, cells")
    ap.add_argument("--contact", choices=("particle", "grid"), default="particle")
    ap.add_argument("--speed-fraction", type=float, default=0.1, help="hand speed between holds / P-wave speed")
    ap.add_argument("--out", type=Path, default=None, help="folder for the table, JSON and plot")
    ap.add_argument("--combine", type=Path, nargs="+", default=None, help="plot these --out folders together")
    args = ap.parse_args(argv)
    if args.combine:
        combine(args.combine, args.out if args.out is not None else Path("."))
        return 0
    size = SIZES[args.size]
    t0 = time.process_time()
    r = slab_press(
        tuple(args.offsets),
        E=E0,
        nu=NU0,
        contact=args.contact,
        speed_fraction=args.speed_fraction,
        max_depth=size["holds"][-1],
        holds=size["holds"],
        **size["scene"],
    )
    assert r.hold is not None
    res = {
        "contact": args.contact,
        "scene": size["scene"],
        "holds": size["holds"],
        "hold_steps": int(min((h == len(size["holds"]) - 1).sum() for h in r.hold)),
        "d_cmp": size["d_cmp"],
        "rows": rows(r, size["holds"], size["d_cmp"]),
        "particles": r.particles,
        "steps": r.steps,
        "cpu_s": time.process_time() - t0,
    }
    text = table(res)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "hertz_static.md").write_text(text + "\n")
        (args.out / "hertz_static.json").write_text(json.dumps(res, indent=1))
        plot(r, res, args.out / "hertz_static.png")
        # the per-step traces, to plot one-offset runs together
        np.savez_compressed(
            args.out / "hertz_static_traces.npz",
            offsets=np.asarray(r.offsets),
            depth=r.depth,
            force=r.force,
            radius=r.radius,
            hold=r.hold,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
