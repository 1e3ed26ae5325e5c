"""How far the contact patches lie from the object's surface, grid against particle contact (not a test).

    OMP_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_patch_surface.py [--touches 12] [--pad 32 --layers 4
        --n-grid 64]

Each touch (one class of ``available_classes()`` each, seeded cone-policy touch; default: the ``cls_paper_cpu`` pad,
32x32x4 on 64^3) is pressed with ``PressConfig(contact="grid", threshold_grid=None)`` (the press before issue 15
item 1) and with the default (particle contact, threshold in 128-grid cells). The contact patch of each reading
(:func:`tvrecon.sim.press.reading.reading_patch`: the pushed-in taxels, normal channel > ``DEFAULT_MIN_PUSH``, mapped
back to world points) is compared with the mesh: signed distance of every patch point (trimesh, > 0 inside the object),
in grid cells. Prints per contact the patch points, their mean |distance|, the share within 0.2 cells and the mean
signed distance, and the mean depth at the stop; then what the tactile images hold (means over the touches): the
largest normal displacement, the largest shear and the share of taxels pushed in, in cells.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import torch
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.reading import reading_patch  # noqa: E402
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402

CONTACTS = {"grid (before)": {"contact": "grid", "threshold_grid": None}, "particle (default)": {}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--touches", type=int, default=12, help="touches, one class each")
    ap.add_argument("--pad", type=int, default=32, help="pad resolution H = W")
    ap.add_argument("--layers", type=int, default=4)
    ap.add_argument("--n-grid", type=int, default=64)
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    sensor = SensorConfig(resolution=(args.pad, args.pad), layers=args.layers)
    sims = {k: EIPSimulator(sensor, PressConfig(n_grid=args.n_grid, **kw)) for k, kw in CONTACTS.items()}
    dist: dict[str, list[np.ndarray]] = {k: [] for k in CONTACTS}
    depth: dict[str, list[float]] = {k: [] for k in CONTACTS}
    image: dict[str, list[tuple[float, float, float]]] = {k: [] for k in CONTACTS}
    cell = 1.0 / args.n_grid
    for i in range(args.touches):
        mesh = make_shape(available_classes()[i % len(available_classes())], 0)
        t = sample_touches(mesh, 1, seed=i, sim=sims["grid (before)"])
        for k, sim in sims.items():
            r = sim.press(mesh, t.positions[0], t.directions[0], **t.strengths[0])
            p = reading_patch(r, sim.sensor, sim.cfg)
            pts = p.points[p.mask].double().numpy()
            if len(pts):
                dist[k].append(trimesh.proximity.signed_distance(mesh, pts) / cell)
            depth[k].append(float(r.depth))
            im = r.image  # (3, H, W) cells
            image[k].append((float(im[2].max()), float(im[:2].norm(dim=0).max()), float(p.mask.float().mean())))
    print(
        f"{args.touches} touches, pad {args.pad}x{args.pad}x{args.layers} on {args.n_grid}^3; distances of the "
        "patch points to the surface in cells (signed: > 0 inside the object)"
    )
    print("| contact | patch points | mean abs distance | within 0.2 cells | mean signed | mean depth at the stop |")
    print("| --- | --- | --- | --- | --- | --- |")
    for k in CONTACTS:
        d = np.concatenate(dist[k]) if dist[k] else np.zeros(0)
        print(
            f"| {k} | {len(d)} | {np.abs(d).mean():.3f} | {(np.abs(d) < 0.2).mean():.1%} | {d.mean():+.3f} | "
            f"{np.mean(depth[k]):.2f} |"
        )

    print("\n| contact | max normal (cells) | max shear (cells) | taxels pushed in |")
    print("| --- | --- | --- | --- |")
    for k in CONTACTS:
        a = np.array(image[k])
        print(f"| {k} | {a[:, 0].mean():.2f} | {a[:, 1].mean():.3f} | {a[:, 2].mean():.1%} |")


if __name__ == "__main__":
    main()
