"""Physics validation of the solver (issue 15 item 2): Hertz contact, stiffness scaling, release, resolution
convergence, momentum and energy. Prints a table and writes plots to ``--out``.

    OMP_NUM_THREADS=1 python benchmarks/bench_physics.py --size small --out outputs/bench_physics   # ~3 CPU-min
    OMP_NUM_THREADS=1 python benchmarks/bench_physics.py --size full --out outputs/bench_physics    # idle machine

``small`` is a scaled-down version of every check; ``full`` uses the sizes of the issue's targets (a 128-cell pad
12 cells thick for Hertz, n_grid 128 vs 256 for the images, 64 / 128 / 256 for the stop depth). The scenes and the
theory live in :mod:`physics_checks`; ``docs/physics.md`` explains the numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from tvrecon.sim.mpm import MPMConfig, cfl_dt
from tvrecon.sim.mpm.materials import lame_parameters, p_wave_speed
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.config import DEFAULT_THRESHOLD
from tvrecon.sim.sensor import SensorConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "sim"))  # the physics checks live with the tests
from tvrecon.sim.validation.physics_checks import (
    draw_contact_theory,
    free_oscillation,
    free_slab_impact,
    hertz_force,
    hertz_radius,
    label_contact_axes,
    loglog_slope,
    slab_press,
    winkler_force,
    winkler_radius,
)

OFFSETS = (0.0, 0.25, 0.5, 0.75)

SIZES = {
    "tiny": {  # a smoke run of the script (seconds), not a measurement
        "hertz": {"n_grid": 32, "width": 8.0, "thick": 2.0, "R": 4.0, "max_depth": 1.5},
        "thick_ref": 4.0,
        "scaling": {"n_grid": 32, "width": 6.0, "thick": 2.0, "R": 4.0, "max_depth": 1.0},
        "release_grid": 64,
        "release_pad": {"resolution": (16, 16), "layers": 4},
        "grids": (32, 64),
        "pair": (32, 64),
        "energy": {"n_grid": 32, "width": 4.0, "thick": 4.0, "periods": 1.0},
    },
    "small": {
        "hertz": {"n_grid": 128, "width": 32.0, "thick": 6.0, "R": 12.0, "max_depth": 3.0},
        "thick_ref": 18.0,
        "scaling": {"n_grid": 64, "width": 16.0, "thick": 4.0, "R": 8.0, "max_depth": 2.0},
        "release_grid": 128,
        "grids": (32, 64, 128),
        "pair": (64, 128),
        "energy": {"n_grid": 64, "width": 8.0, "thick": 8.0, "periods": 4.0},
    },
    "full": {
        "hertz": {"n_grid": 256, "width": 128.0, "thick": 12.0, "R": 32.0, "max_depth": 4.0},
        "thick_ref": 36.0,
        "scaling": {"n_grid": 128, "width": 32.0, "thick": 6.0, "R": 12.0, "max_depth": 3.0},
        "release_grid": 128,
        "grids": (64, 128, 256),
        "pair": (128, 256),
        "energy": {"n_grid": 128, "width": 16.0, "thick": 16.0, "periods": 4.0},
    },
}

E0, NU0 = 3.0, 0.25


def _cpu() -> float:
    return time.process_time()


# ---------------------------------------------------------------------------------------------------- 1. Hertz
def bench_hertz(size: dict, contact: str = "grid") -> dict:
    """Hertz press at the four apex offsets and the thick reference, with ``MPMConfig.contact`` = ``contact``."""
    h = size["hertz"]
    t0 = _cpu()
    thin = slab_press(OFFSETS, E=E0, nu=NU0, contact=contact, **h)
    t_thin = _cpu() - t0
    t0 = _cpu()
    thick = slab_press((0.5,), E=E0, nu=NU0, contact=contact, **{**h, "thick": size["thick_ref"]})
    t_thick = _cpu() - t0
    R, dx, hh, dmax = h["R"], thin.dx, h["thick"], h["max_depth"]
    lo = 0.75  # fit range in cells: from 3/4 cell to the final depth
    d_cmp = round(2.0 / 3.0 * dmax, 2)
    rows = []
    for b, off in enumerate(OFFSETS):
        d, f, a = thin.depth[b], thin.force[b], thin.radius[b]
        first = float(d[np.argmax(f > 0)]) if (f > 0).any() else float("nan")
        f2 = float(np.interp(d_cmp, d, f))
        rows.append(
            {
                "offset": off,
                "first_contact_depth": first,
                "force_exponent": loglog_slope(d, f, lo, dmax),
                "radius_exponent": loglog_slope(d, a, lo, dmax),
                "area_radius_exponent": loglog_slope(d, thin.area_radius[b], lo, dmax),
                "force_exponent_from_first": loglog_slope(d - first, f, lo, dmax),
                "F/F_hertz": f2 / float(hertz_force(E0, NU0, R * dx, d_cmp * dx)),
                "F/F_winkler": f2 / float(winkler_force(E0, NU0, R * dx, hh * dx, d_cmp * dx)),
                "a": float(np.interp(d_cmp, d, a)),
            }
        )
    d, f, a = thick.depth[0], thick.force[0], thick.radius[0]
    f2 = float(np.interp(d_cmp, d, f))
    first = float(d[np.argmax(f > 0)])
    ref = {
        "thick": size["thick_ref"],
        "first_contact_depth": first,
        "force_exponent_from_first": loglog_slope(d - first, f, lo, dmax),
        "force_exponent": loglog_slope(d, f, lo, dmax),
        "radius_exponent": loglog_slope(d, a, lo, dmax),
        "F/F_hertz": f2 / float(hertz_force(E0, NU0, R * dx, d_cmp * dx)),
        "a": float(np.interp(d_cmp, d, a)),
        "F_thin/F_thick": float(np.interp(d_cmp, thin.depth[2], thin.force[2])) / f2,
    }
    return {
        "contact": contact,
        "cfg": h,
        "d_cmp": d_cmp,
        "hertz_a": float(hertz_radius(R, d_cmp)),
        "winkler_a": float(winkler_radius(R, d_cmp)),
        "rows": rows,
        "ref": ref,
        "thin": thin,
        "thick": thick,
        "cpu_s": {"thin": t_thin, "thick": t_thick},
        "particle_steps": thin.particles * thin.steps + thick.particles * thick.steps,
    }


# ---------------------------------------------------------------------------------------------------- 2. scaling
def bench_scaling(size: dict) -> dict:
    s = size["scaling"]
    mats = [(1.0, NU0), (3.0, NU0), (9.0, NU0), (3.0, 0.1), (3.0, 0.4)]
    # one hand speed and one dt for every material: slow for the softest, stable for the stiffest
    speed = 0.1 * min(p_wave_speed(E, nu, 1.0) for E, nu in mats)
    dt = min(cfl_dt(MPMConfig(n_grid=s["n_grid"], E=E, nu=nu)) for E, nu in mats)
    d_cmp = s["max_depth"] * 0.75
    t0 = _cpu()
    F = {}
    for E, nu in mats:
        r = slab_press((0.5,), E=E, nu=nu, dt=dt, speed=speed, **s)
        F[(E, nu)] = float(np.interp(d_cmp, r.depth[0], r.force[0]))
        steps, parts = r.steps, r.particles
    # the press protocol: hand speed a fixed fraction of each material's P-wave speed, CFL dt of each material
    F_press = {}
    for E in (1.0, 3.0, 9.0):
        r = slab_press((0.5,), E=E, nu=NU0, **s)
        F_press[E] = float(np.interp(d_cmp, r.depth[0], r.force[0]))
    cpu = _cpu() - t0

    def M(E: float, nu: float) -> float:
        mu, lam = lame_parameters(E, nu)
        return float(lam) + 2 * float(mu)

    e_rows = [
        {"E": E, "F/F(E=3)": F[(E, NU0)] / F[(3.0, NU0)], "press": F_press[E] / F_press[3.0], "E/3": E / 3.0}
        for E in (1.0, 3.0, 9.0)
    ]
    nu_rows = [
        {
            "nu": nu,
            "F/F(nu=0.25)": F[(3.0, nu)] / F[(3.0, NU0)],
            "hertz": (1 - NU0**2) / (1 - nu**2),
            "winkler": M(3.0, nu) / M(3.0, NU0),
        }
        for nu in (0.1, 0.25, 0.4)
    ]
    return {"cfg": s, "d_cmp": d_cmp, "E": e_rows, "nu": nu_rows, "cpu_s": cpu, "particle_steps": 5 * steps * parts}


# ---------------------------------------------------------------------------------------------------- 3. release
def bench_release(size: dict) -> dict:
    n = size["release_grid"]
    pad = size.get("release_pad", {})  # default: the default pad
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    out = {}
    t0 = _cpu()
    for prof in ("clamped", "linear"):
        # the grid contact, as measured in docs/physics.md section 3 (the press's default then)
        press = PressConfig(n_grid=n, depth=2.0, release_steps=300, contact="grid", threshold_grid=None)
        sim = EIPSimulator(SensorConfig(alpha_profile=prof, **pad), press)
        r = sim.press(mesh, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0])
        res = r.residual
        out[prof] = {
            "depth": r.depth,
            "peak": float(r.image[2].max()),
            "residual_max": float(res.abs().max()),
            "residual_normal_max": float(res[2].abs().max()),
            "residual_mean": float(res.norm(dim=0).mean()),
        }
    out["cpu_s"] = _cpu() - t0
    return out


# ---------------------------------------------------------------------------------------------------- 4. resolution
def scaled_pad(n_grid: int) -> SensorConfig:
    """The same physical pad at any n_grid: 1/4 of the domain wide, 1/32 thick, spacing 0.5 cells."""
    return SensorConfig(resolution=(n_grid // 2, n_grid // 2), layers=n_grid // 16 + 1, spacing=0.5)


def _corr(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.flatten().double(), b.flatten().double()
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / (a.norm() * b.norm()).clamp(min=1e-30))


#: reference grid of the physical stop threshold (``PressConfig.threshold_grid``, also its default): the paper's
#: threshold at the default n_grid
THRESHOLD_GRID = 128


def bench_resolution(size: dict, contact: str = "grid", threshold_grid: int | None = None) -> dict:
    """Depth at the terminal-chamfer stop over ``size["grids"]`` and the image correlation of ``size["pair"]`` at one
    physical depth, with ``PressConfig.contact`` and ``threshold_grid`` as given (defaults: the grid contact and the
    threshold in the press's own cells, the default press before issue 15 item 1)."""
    from tvrecon.sim.__main__ import load_shape

    opts = {"contact": contact, "threshold_grid": threshold_grid}

    mesh = load_shape("gear")
    direction = [0.0, 0.0, -1.0]
    c, f = size["pair"]
    pos = EIPSimulator(scaled_pad(c), PressConfig(n_grid=c)).touch_position(mesh, direction)
    t0 = _cpu()
    stops = []
    for n in size["grids"]:
        r = EIPSimulator(scaled_pad(n), PressConfig(n_grid=n, **opts)).press(mesh, pos, direction)
        stops.append({"n_grid": n, "depth_cells": r.depth, "depth_domain": r.depth / n, "steps": r.steps})
    base = stops[-1]["depth_domain"]
    for s in stops:
        s["rel_to_finest"] = s["depth_domain"] / base if base > 0 else float("nan")
    # the same physical depth (1.5 cells of the coarse grid) at both resolutions; images in domain units
    imgs = {}
    for n in (c, f):
        press = PressConfig(n_grid=n, depth=1.5 * n / c, contact=contact)
        r = EIPSimulator(scaled_pad(n), press).press(mesh, pos, direction)
        imgs[n] = r.image / n
    fine = torch.nn.functional.avg_pool2d(imgs[f][None], 2)[0]  # fine pixel pairs centred on the coarse pixels
    corr = {"normal": _corr(imgs[c][2], fine[2]), "shear": _corr(imgs[c][:2], fine[:2])}
    return {**opts, "stops": stops, "pair": (c, f), "corr": corr, "images": imgs, "cpu_s": _cpu() - t0}


# ------------------------------------------------------------------------------------------------- 5. momentum, energy
def bench_conservation(size: dict) -> dict:
    t0 = _cpu()
    mom = free_slab_impact()
    osc = free_oscillation(**size["energy"])
    tot = osc["total"]
    p = osc["momentum"]
    return {
        "momentum_rel_error": mom["rel_error"],
        "impulse_rel": mom["impulse_rel"],
        "energy_final": float(tot[-1] / tot[0]),
        "energy_max": float(tot.max() / tot[0]),
        "energy_min": float(tot.min() / tot[0]),
        "free_momentum_drift": float(np.abs(p - p[0]).max() / (np.sqrt(2 * tot[0] * 1.0) + 1e-30)),
        "osc": osc,
        "cfg": size["energy"],
        "cpu_s": _cpu() - t0,
    }


# ---------------------------------------------------------------------------------------------------- plots
def plots(res: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for key, name in (("hertz", "physics_hertz.png"), ("hertz_particle", "physics_hertz_particle.png")):
        if key in res:
            _plot_hertz(plt, res[key], out / name)
    _plot_rest(plt, res, out)


def _plot_hertz(plt, H: dict, path: Path) -> None:
    thin, thick = H["thin"], H["thick"]
    R, dx, h = thin.R, thin.dx, thin.thick
    Es = E0 / (1 - NU0**2)
    unit = Es * dx**2  # forces shown as F / (E* dx^2): cells^2
    dd = np.linspace(0.05, thin.depth.max(), 200)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for b, off in enumerate(thin.offsets):
        m = thin.depth[b] > 0.05
        ax[0].loglog(thin.depth[b][m], thin.force[b][m] / unit, label=f"h={h:g}, apex +{off:g} cell")
        ax[1].plot(thin.depth[b], thin.radius[b], label=f"h={h:g}, apex +{off:g} cell")
    m = thick.depth[0] > 0.05
    ax[0].loglog(thick.depth[0][m], thick.force[0][m] / unit, "k--", label=f"h={thick.thick:g} (half-space ref.)")
    ax[1].plot(thick.depth[0], thick.radius[0], "k--", label=f"h={thick.thick:g}")
    draw_contact_theory(ax, E0, NU0, R, h, dx, dd)
    label_contact_axes(ax, f"force, sphere R={R:g} cells, {H['contact']} contact", radius_xmin=-1.5, force_ymin=1e-1)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def _plot_rest(plt, res: dict, out: Path) -> None:

    S = res["scaling"]
    fig, ax = plt.subplots(1, 2, figsize=(8, 3.2))
    ax[0].plot([r["E"] for r in S["E"]], [r["F/F(E=3)"] for r in S["E"]], "o-", label="fixed speed, dt")
    ax[0].plot([r["E"] for r in S["E"]], [r["press"] for r in S["E"]], "s--", label="press protocol")
    ax[0].plot([1, 9], [1 / 3, 3], "k:", label="linear")
    ax[0].set(xlabel="E", ylabel="F / F(E=3)", title=f"force at d={S['d_cmp']:g} cells vs E")
    ax[1].plot([r["nu"] for r in S["nu"]], [r["F/F(nu=0.25)"] for r in S["nu"]], "o-", label="measured")
    ax[1].plot([r["nu"] for r in S["nu"]], [r["hertz"] for r in S["nu"]], "k:", label="Hertz 1/(1-nu^2)")
    ax[1].plot([r["nu"] for r in S["nu"]], [r["winkler"] for r in S["nu"]], "r:", label="thin layer lambda+2mu")
    ax[1].set(xlabel="nu", ylabel="F / F(nu=0.25)", title="force vs nu")
    for a in ax:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "physics_scaling.png", dpi=72)
    plt.close(fig)

    C = res["conservation"]["osc"]
    fig, ax = plt.subplots(figsize=(5, 3.2))
    e0 = C["total"][0]
    ax.plot(C["t"], C["elastic"] / e0, label="elastic")
    ax.plot(C["t"], C["kinetic"] / e0, label="kinetic")
    ax.plot(C["t"], C["total"] / e0, "k", label="total")
    ax.set(xlabel="t", ylabel="energy / E(0)", title="free oscillation (no collider)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "physics_energy.png", dpi=72)
    plt.close(fig)

    for key, name in (
        ("resolution", "physics_resolution.png"),
        ("resolution_particle", "physics_resolution_particle.png"),
    ):
        if key in res:
            _plot_images(plt, res[key], out / name)


def _plot_images(plt, Rz: dict, path: Path) -> None:
    c, f = Rz["pair"]
    imgs = Rz["images"]
    fine = torch.nn.functional.avg_pool2d(imgs[f][None], 2)[0]
    fig, ax = plt.subplots(2, 3, figsize=(8, 5.2))
    for row, (n, im) in enumerate(((c, imgs[c]), (f, fine))):
        ax[row, 0].imshow(im[2].numpy(), cmap="viridis")
        ax[row, 0].set_title(f"n_grid {n}: normal", fontsize=8)
        ax[row, 1].imshow(im[0].numpy(), cmap="RdBu")
        ax[row, 1].set_title(f"n_grid {n}: shear x", fontsize=8)
        ax[row, 2].imshow(im[1].numpy(), cmap="RdBu")
        ax[row, 2].set_title(f"n_grid {n}: shear y", fontsize=8)
    for a in ax.flat:
        a.set_axis_off()
    fig.suptitle(f"gear, {Rz['contact']} contact, same physical depth; {f} pooled 2x2 "
                 f"(corr normal {Rz['corr']['normal']:.3f}, shear {Rz['corr']['shear']:.3f})", fontsize=9)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------- report
def _hertz_table(H: dict) -> list[str]:
    c = H["cfg"]
    L = [
        f"## 1. Hertz, {H['contact']} contact: sphere R={c['R']:g} cells into a {c['width']:g}-cell pad "
        f"{c['thick']:g} cells thick (n_grid {c['n_grid']}), fit d in [0.75, {c['max_depth']:g}] cells, ratios at "
        f"d={H['d_cmp']:g}",
        "| apex offset (cell) | first contact at d (cells) | force exponent | force exponent from first contact | "
        "radius exponent | area-radius exponent | a (cells) | F / F_Hertz | F / F_thin-layer |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in H["rows"]:
        L.append(
            f"| {r['offset']:g} | {r['first_contact_depth']:.2f} | {r['force_exponent']:.2f} | "
            f"{r['force_exponent_from_first']:.2f} | {r['radius_exponent']:.2f} | {r['area_radius_exponent']:.2f} | "
            f"{r['a']:.2f} | {r['F/F_hertz']:.2f} | {r['F/F_winkler']:.2f} |"
        )
    r = H["ref"]
    L.append(
        f"| 0.5, h={r['thick']:g} (half-space ref.) | {r['first_contact_depth']:.2f} | {r['force_exponent']:.2f} | "
        f"{r['force_exponent_from_first']:.2f} | {r['radius_exponent']:.2f} | | "
        f"{r['a']:.2f} | {r['F/F_hertz']:.2f} | |"
    )
    L.append(
        f"\nTheory at d={H['d_cmp']:g}: Hertz a = {H['hertz_a']:.2f}, thin layer a = {H['winkler_a']:.2f} cells; "
        f"F(h={c['thick']:g}) / F(h={r['thick']:g}) = {r['F_thin/F_thick']:.2f} (offset 0.5)\n"
    )
    return L


def table(res: dict) -> str:
    L = []
    for key in ("hertz", "hertz_particle"):
        if key in res:
            L += _hertz_table(res[key])
    S = res["scaling"]
    L.append(f"\n## 2. Stiffness scaling: force at d={S['d_cmp']:g} cells, one dt and hand speed for all")
    L.append("| E | F / F(E=3), fixed speed and dt | F / F(E=3), press protocol (0.1 c_p, CFL dt) | E / 3 |")
    L.append("| --- | --- | --- | --- |")
    for r in S["E"]:
        L.append(f"| {r['E']:g} | {r['F/F(E=3)']:.4f} | {r['press']:.4f} | {r['E/3']:.4f} |")
    L.append("\n| nu | F / F(nu=0.25) | Hertz (1-0.25^2)/(1-nu^2) | thin layer M(nu)/M(0.25) |")
    L.append("| --- | --- | --- | --- |")
    for r in S["nu"]:
        L.append(f"| {r['nu']:g} | {r['F/F(nu=0.25)']:.3f} | {r['hertz']:.3f} | {r['winkler']:.3f} |")
    Rl = res["release"]
    L.append(
        "\n## 3. Release (default pad or `release_pad`, sphere, pressed 2 cells, 300 release steps): residual in cells"
    )
    L.append("| alpha profile | depth (cells) | peak normal (cells) | residual max | residual normal max | "
             "residual mean |")  # fmt: skip
    L.append("| --- | --- | --- | --- | --- | --- |")
    for prof in ("clamped", "linear"):
        r = Rl[prof]
        L.append(
            f"| {prof} | {r['depth']:.2f} | {r['peak']:.2f} | {r['residual_max']:.3f} | "
            f"{r['residual_normal_max']:.3f} | {r['residual_mean']:.3f} |"
        )
    for key in ("resolution", "resolution_physical", "resolution_particle"):
        if key not in res:
            continue
        Z = res[key]
        unit = "own cells" if Z["threshold_grid"] is None else f"cells of a {Z['threshold_grid']}-cell grid"
        L.append(
            f"\n## 4. Resolution, {Z['contact']} contact (gear, pad 1/4 domain wide, 1/32 thick): depth at the "
            f"terminal-chamfer stop, threshold {DEFAULT_THRESHOLD} squared {unit}"
        )
        L.append("| n_grid | depth (cells) | depth (domain) | / finest |")
        L.append("| --- | --- | --- | --- |")
        for s in Z["stops"]:
            L.append(f"| {s['n_grid']} | {s['depth_cells']:.2f} | {s['depth_domain']:.5f} | {s['rel_to_finest']:.2f} |")
        c, f = Z["pair"]
        L.append(
            f"\nImage correlation n_grid {c} vs {f} (same physical depth): normal {Z['corr']['normal']:.3f}, "
            f"shear {Z['corr']['shear']:.3f}"
        )
    C = res["conservation"]
    L.append("\n## 5. Momentum and energy")
    L.append(
        f"- free slab hitting a sphere (friction 0.5): max |dp - impulse| / |p0| = {C['momentum_rel_error']:.1e} "
        f"(impulse / |p0| = {C['impulse_rel']:.2f})"
    )
    e = C["cfg"]
    L.append(
        f"- free oscillation ({e['width']:g}x{e['width']:g}x{e['thick']:g} cells, n_grid {e['n_grid']}, "
        f"{e['periods']:g} periods): total energy final {C['energy_final']:.3f}, max {C['energy_max']:.4f}, "
        f"min {C['energy_min']:.3f} of the start"
    )
    L.append("\n## CPU seconds")
    cpu = {k: v["cpu_s"] for k, v in res.items() if isinstance(v, dict) and "cpu_s" in v}
    L.append(", ".join(f"{k}: {json.dumps(v) if isinstance(v, dict) else f'{v:.1f}'}" for k, v in cpu.items()))
    return "\n".join(L)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", choices=sorted(SIZES), default="small")
    ap.add_argument("--out", type=Path, default=Path("outputs/bench_physics"))
    ap.add_argument("--only", nargs="*", default=None, help="subset of the benches (names in main)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    size = SIZES[args.size]
    benches = {
        "hertz": bench_hertz,
        "hertz_particle": lambda size: bench_hertz(size, "particle"),
        "scaling": bench_scaling,
        "release": bench_release,
        "resolution": bench_resolution,
        "resolution_physical": lambda size: bench_resolution(size, "grid", THRESHOLD_GRID),
        "resolution_particle": lambda size: bench_resolution(size, "particle", THRESHOLD_GRID),
        "conservation": bench_conservation,
    }
    res = {}
    t0 = _cpu()
    for name, fn in benches.items():
        if args.only is None or name in args.only:
            t = _cpu()
            res[name] = fn(size)
            print(f"[{name}] {(_cpu() - t):.1f} CPU-s", flush=True)
    if args.only is None:
        plots(res, args.out)
        txt = table(res)
        txt += f"\n\ntotal {(_cpu() - t0):.1f} CPU-s, size {args.size}, torch threads {torch.get_num_threads()}"
        print(txt)
        (args.out / "physics.md").write_text(txt + "\n")

    def plain(o):
        if dataclasses.is_dataclass(o):
            return {k: plain(v) for k, v in dataclasses.asdict(o).items()}
        if isinstance(o, dict):
            return {str(k): plain(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [plain(v) for v in o]
        if isinstance(o, (np.ndarray, torch.Tensor)):
            return np.asarray(o).tolist()
        if isinstance(o, float) and not math.isfinite(o):
            return None
        return o

    (args.out / "physics.json").write_text(json.dumps(plain(res)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
