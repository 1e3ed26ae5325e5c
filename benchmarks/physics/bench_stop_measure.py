"""Why the terminal chamfer's stop depth changes with n_grid on flat faces: eq. 12 against the
displacement it stands for, on objects of the library.

Each shape is pressed from the top as in ``bench_stop_depth.py`` (``scaled_pad``, particle contact, 0.1 c_p, the
default stop: paper eq. 12 with ``threshold_grid=128``), recording the contact layer at every step
(``record_every=1``). From each recorded image ``u`` (cells, hand translation removed) two measures are taken:

- **chamfer**: :func:`terminal_chamfer` of ``rest + u`` against ``rest``, what the press stops on (eq. 12: nearest
  neighbours, no correspondence between the deformed and the rest particles);
- **displacement**: ``2 mean_p |u_p - mean(u)|^2``, the same deformation with the correspondence. It bounds the
  chamfer from above (each chamfer term is at most ``mean_p |u_p - mean(u)|^2``) and equals it while every
  particle's in-plane motion stays under half the lattice spacing (0.25 cells).

The stop depth of each measure is the depth at the first step where it reaches the threshold (for the chamfer: the
press's own stop). Per shape and grid the table gives both depths (domain units), their ratios to the finest grid,
and at the chamfer stop the in-plane share of the displacement and the largest in-plane motion in lattice spacings.
``travel``: the press reached its travel limit (``max_depth``, 4 cells of its own grid) before the chamfer threshold.

    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_measure --grids 64 128 256 --shapes cube gear ball pencil
    OMP_NUM_THREADS=1 python -m benchmarks.physics.bench_stop_measure --shapes gear cube \\
        --plot docs/img/stop_measure.png

``--plot`` saves, per shape, the contact layer at each grid's chamfer stop: the centred normal displacement and the
in-plane motion in lattice spacings (the chamfer saturates above 0.5).
"""

from __future__ import annotations

import argparse
import time

import torch

from benchmarks.physics.bench_physics import scaled_pad
from benchmarks.physics.bench_stop_depth import shape_mesh
from tvrecon.data.shapes import available_classes
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.stop_rules import terminal_chamfer, threshold_cells
from tvrecon.sim.sensor import pad_lattice


def measures(frames: torch.Tensor, rest: torch.Tensor, lattice: tuple[int, int, float]) -> torch.Tensor:
    """(K, 2) chamfer and displacement measure (squared cells) of K recorded images.

    Args:
        frames: (K, 3, H, W) contact-layer displacement in cells. rest: (H*W, 3) rest contact layer in cells.
    """
    out = []
    for img in frames.double():
        u = img.permute(1, 2, 0).reshape(-1, 3)  # (HW, 3) in the lattice's order
        uc = u - u.mean(0)
        out.append((terminal_chamfer(rest.double() + u, rest.double(), lattice), 2 * float((uc**2).sum(1).mean())))
    return torch.tensor(out, dtype=torch.float64)


def press_shape(name: str, grids: list[int]) -> list[dict]:
    """One row per grid: stop depths of both measures (domain units) and the in-plane numbers at the chamfer stop."""
    mesh = shape_mesh(name)
    direction = [0.0, 0.0, -1.0]
    pos = EIPSimulator(scaled_pad(128), PressConfig(n_grid=128)).touch_position(mesh, direction)
    rows = []
    for n in grids:
        s, p = scaled_pad(n), PressConfig(n_grid=n, record_every=1)
        t0 = time.process_time()
        r = EIPSimulator(s, p).press(mesh, pos, direction)
        step_cells = (r.depth + float(p.gap)) / r.steps  # the hand's travel (gap + depth) is steps x one step
        H, W = s.resolution
        rest = pad_lattice(s)[: H * W]
        m = measures(r.frames, rest, (H, W, float(s.spacing)))
        depth = [r.depth - (r.steps - k) * step_cells for k in r.frame_steps]  # cells, at each recorded step
        T = threshold_cells(p)
        k_d = next((i for i, v in enumerate(m[:, 1].tolist()) if v >= T), None)
        u = r.frames[-1].double().permute(1, 2, 0).reshape(-1, 3)
        uc = u - u.mean(0)
        inplane = float((uc[:, :2] ** 2).sum() / (uc**2).sum().clamp(min=1e-30))
        rows.append(
            dict(
                n=n,
                chamfer=r.depth / n,
                displacement=(max(depth[k_d], 0.0) / n) if k_d is not None else float("nan"),
                travel=r.depth >= float(p.max_depth) - 1e-3,
                inplane_share=inplane,
                inplane_max=float(uc[:, :2].norm(dim=1).max()) / float(s.spacing),
                check=abs(float(m[-1, 0]) - r.chamfer) / max(r.chamfer, 1e-30),
                cpu=time.process_time() - t0,
                image=r.frames[-1] / n,  # (3, H, W) domain units
                spacing=float(s.spacing) / n,
            )
        )
    return rows


def depth_cells(rows: list[dict], key: str) -> tuple[str, str]:
    """Table cells: the depths of ``key`` per grid, and their ratios to the last (finest) grid."""
    vals = [r[key] for r in rows]
    return " / ".join(f"{v:.5f}" for v in vals), " / ".join(f"{v / vals[-1]:.2f}" for v in vals[:-1])


def plot(path: str, results: list[tuple[str, list[dict]]]) -> None:
    """One row per shape: centred normal displacement (domain units) and in-plane motion (spacings) per grid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    G = len(results[0][1])
    fig, axes = plt.subplots(len(results), 2 * G, figsize=(3.0 * 2 * G, 3.0 * len(results)), squeeze=False)
    for row, (name, rows) in zip(axes, results):
        for k, r in enumerate(rows):
            img = r["image"].double()
            w = img[2] - img[2].mean()
            ip = (img[:2] - img[:2].mean((1, 2), keepdim=True)).norm(dim=0) / r["spacing"]
            a = row[k].imshow(w.numpy(), cmap="RdBu_r")
            row[k].set_title(f"{name} {r['n']}: normal, depth {r['chamfer']:.4f}", fontsize=8)
            fig.colorbar(a, ax=row[k], fraction=0.046)
            b = row[G + k].imshow(ip.numpy(), cmap="viridis")
            row[G + k].set_title(f"{name} {r['n']}: in-plane / spacing", fontsize=8)
            fig.colorbar(b, ax=row[G + k], fraction=0.046)
        for a in row:
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    print(f"saved {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grids", type=int, nargs="+", default=[64, 128, 256])
    ap.add_argument("--shapes", nargs="+", default=["cube", "gear", "ball"], help="library names, sphere, or all")
    ap.add_argument("--plot", default=None, help="save the contact layers at the stops to this image")
    args = ap.parse_args(argv)
    g = args.grids
    print(
        "| shape | chamfer stop " + " / ".join(map(str, g)) + " | ratios to " + str(g[-1]) + " | displacement stop "
        "| ratios | in-plane share at the stop | in-plane max / spacing | CPU-s |"
    )
    print("| --- " * 8 + "|")
    results = []
    for name in available_classes() if args.shapes == ["all"] else args.shapes:
        rows = press_shape(name, g)
        results.append((name, rows))
        worst = max(r["check"] for r in rows)
        if worst > 1e-4:  # the recorded layer must reproduce the press's own chamfer
            raise RuntimeError(f"{name}: recorded chamfer differs from the reading's by {worst:.2e} (relative)")

        (cd, cr), (dd, dr) = depth_cells(rows, "chamfer"), depth_cells(rows, "displacement")
        travel = (
            " (travel: " + ", ".join(str(r["n"]) for r in rows if r["travel"]) + ")"
            if any(r["travel"] for r in rows)
            else ""
        )
        share = " / ".join(f"{r['inplane_share']:.2f}" for r in rows)
        imax = " / ".join(f"{r['inplane_max']:.2f}" for r in rows)
        cpu = " / ".join(f"{r['cpu']:.1f}" for r in rows)
        print(f"| {name} | {cd}{travel} | {cr} | {dd} | {dr} | {share} | {imax} | {cpu} |", flush=True)
    if args.plot:
        plot(args.plot, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
