"""Where a contact patch leaves the surface: point-to-surface distance by push depth, and what each contact test keeps.

    PROJECT_ROOT=$PWD .venv/bin/python -m benchmarks.physics.bench_patch_rim [--preset paper_cpu] [--split test]
        [--every 5] [--out benchmarks/results/<dir>/patch_rim.png]

A touch's contact patch (:func:`tvrecon.sim.sensor.patch.contact_patch`) is the pad's contact layer mapped back to
world points, kept where the pad was pushed in. The points of a contact's rim are pushed in a little because their
neighbours are, not because the object stops them, so they lie off the surface. On the preset's cached split (the
paper's touches; items generated on a miss) this prints

1. the signed distance (trimesh, > 0 inside the object) of the contact-layer points to the mesh, by the depth they
   were pushed in (cells), on every ``--every``-th item;
2. per class, for the default absolute test (0.1 cell), a stricter absolute one and relative ones (a fraction of each
   touch's deepest push: ``data.patch_min_push_fraction``): the contact points of 10 touches, the touches left
   without a point, and the two terms of the chamfer between the touches' contact cloud and the GT surface samples
   (x1e-3, the Table 3 unit): GT -> cloud (what the touches do not cover) and cloud -> GT (how far the kept points
   are from the surface).

With ``--out``, a figure of (1).
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
import trimesh

from benchmarks._common import ROOT

os.environ.setdefault("PROJECT_ROOT", str(ROOT))

from tvrecon.data.presets import compose_preset
from tvrecon.losses.chamfer import chamfer_terms

BANDS = [(0.0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 9.0)]
TESTS = {  # name: (patch_min_push, patch_min_push_fraction)
    "absolute 0.1 (default)": (0.1, 0.0),
    "absolute 0.3": (0.3, 0.0),
    "relative 0.25": (0.1, 0.25),
    "relative 0.4": (0.1, 0.4),
}


def push_bands(ds, every: int, cell: float) -> list[tuple[str, int, float, float, float]]:
    """Rows (band, points, mean |distance| cells, mean signed distance cells, share inside) over every ``every``-th
    item of ``ds`` (its first ``max_touches`` touches)."""
    dist, push = [], []
    for i in range(0, len(ds), every):
        raw, _ = ds.raw(i)
        s = ds[i]
        p = torch.from_numpy(np.ascontiguousarray(raw["tactile"][:, 2])).float().flatten(1)  # (M, Q) cells
        keep = p > BANDS[0][0]
        pts = s["patch_points"][: p.shape[0]][keep].double().numpy()
        if len(pts):
            dist.append(trimesh.proximity.signed_distance(ds.mesh(i), pts) / cell)
            push.append(p[keep].numpy())
    d, p = np.concatenate(dist), np.concatenate(push)
    rows = []
    for lo, hi in BANDS:
        sel = (p > lo) & (p <= hi)
        if sel.any():
            rows.append(
                (
                    f"{lo}-{hi}",
                    int(sel.sum()),
                    float(np.abs(d[sel]).mean()),
                    float(d[sel].mean()),
                    float((d[sel] > 0).mean()),
                )
            )
    return rows


def floor_terms(ds) -> dict[str, tuple[float, float, float, int, int]]:
    """Per class: (GT -> cloud, cloud -> GT (x1e-3), contact points, touches without a point, touches)."""
    acc: dict[str, list[tuple[float, float, int, int, int]]] = defaultdict(list)
    for i in range(len(ds)):
        s = ds[i]
        T = int(s["touch_mask"].sum())
        m = s["patch_mask"][:T]
        pts, gt = s["patch_points"][:T][m], s["points"]
        if len(pts):
            c = chamfer_terms(pts[None], gt[None], reduction="none")  # dist_xy: cloud -> GT, dist_yx: GT -> cloud
            terms = (float(c.dist_yx.mean()) * 1e3, float(c.dist_xy.mean()) * 1e3)
        else:
            terms = (float("nan"), float("nan"))
        acc[ds.object_of(i)[0]].append((*terms, len(pts), int((m.sum(1) == 0).sum()), T))
    out = {}
    for c, v in acc.items():
        a = np.array(v, dtype=np.float64)
        out[c] = (np.nanmean(a[:, 0]), np.nanmean(a[:, 1]), a[:, 2].mean(), int(a[:, 3].sum()), int(a[:, 4].sum()))
    a = np.array([[*v] for v in out.values()])
    out["mean"] = (a[:, 0].mean(), a[:, 1].mean(), a[:, 2].mean(), int(a[:, 3].sum()), int(a[:, 4].sum()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="paper_cpu")
    ap.add_argument("--split", default="test")
    ap.add_argument("--every", type=int, default=5, help="signed distances on every n-th item (trimesh is slow)")
    ap.add_argument("--out", type=Path, default=None, help="PNG of the distance by push depth")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from hydra.utils import instantiate

    dm = instantiate(compose_preset(args.preset))
    ds = dm.make_dataset(args.split, num_touches=None)
    cell = float(ds.press.domain_size) / int(ds.press.n_grid)
    rows = push_bands(ds, args.every, cell)
    print(
        f"{args.preset} {args.split}: contact-layer points by push depth, distance to the surface in cells "
        f"(signed: > 0 inside the object), every {args.every}th item"
    )
    print("| pushed in (cells) | points | mean abs distance | mean signed | inside |")
    print("| --- | --- | --- | --- | --- |")
    for band, n, absd, sd, inside in rows:
        print(f"| {band} | {n} | {absd:.3f} | {sd:+.3f} | {inside:.0%} |")
    for name, (absolute, fraction) in TESTS.items():
        t = dm.make_dataset(args.split, patch_min_push=absolute, patch_min_push_fraction=fraction)
        terms = floor_terms(t)
        print(f"\ncontact test {name}: the touches' contact cloud against the GT samples (x1e-3)")
        print("| class | GT -> cloud | cloud -> GT | contact points | touches without a point |")
        print("| --- | --- | --- | --- | --- |")
        for c, (to_cloud, to_gt, pts, empty, total) in terms.items():
            print(f"| {c} | {to_cloud:.2f} | {to_gt:.3f} | {pts:.0f} | {empty}/{total} |")
    if args.out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.bar([r[0] for r in rows], [r[2] for r in rows], color="tab:blue", label="mean |distance|")
        ax.plot([r[0] for r in rows], [r[3] for r in rows], "o-", color="tab:red", label="mean signed (> 0 inside)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("pushed in (cells)")
        ax.set_ylabel("distance to the surface (cells)")
        ax.set_title(f"contact-layer points of {args.preset} {args.split}: the rim lies outside")
        ax.legend()
        fig.tight_layout()
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(".tmp.png")
        fig.savefig(tmp, dpi=120)
        tmp.replace(args.out)
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
