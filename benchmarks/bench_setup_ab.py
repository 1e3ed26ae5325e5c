"""A touch's set-up (``placement.place_touch``: frame, touch point, mesh collider) by an earlier commit and by the
working tree, in one process (not a test).

    OMP_NUM_THREADS=1 python benchmarks/bench_setup_ab.py --old REV [--objects 4] [--per-object 10] [--repeats 3]

The older ``tvrecon`` is imported as ``tvrecon_old`` (``bench_press_ab.import_old``). Paper preset (64x64x6 pad,
n_grid 128), object ``i`` of class ``7 i`` of ``available_classes()`` (wrapping) with ``--per-object`` seeded
cone-policy touches, as ``generate`` presses them: an object's touches share one mesh object (what trimesh caches on
it, e.g. its ray intersector, is shared), and every round starts from new mesh objects (nothing cached from the last
round). Each round places every touch with both versions, alternating which goes first, on one thread. Prints the CPU
milliseconds per touch of both, the old/new ratio per round and overall, and how far apart the placements are: the
touch point, the collider tables (``node_sdf`` in cells, ``node_normal``), the inside/outside sign of the nodes and
the sample count (``--strict``: also whether they are bit-identical, ``torch.equal``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import torch
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_press_ab import import_old  # noqa: E402

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig, placement  # noqa: E402
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402


def same(a, b) -> bool:
    """Both placements unreachable, or the same touch point and bit-identical collider tables."""
    if (a.collider is None) != (b.collider is None):
        return False
    if not torch.equal(a.origin, b.origin):
        return False
    ca, cb = a.collider, b.collider
    return ca is None or (
        torch.equal(ca.node_sdf, cb.node_sdf)
        and torch.equal(ca.node_normal, cb.node_normal)
        and ca.n_samples == cb.n_samples
    )


def apart(a, b, dx: float) -> dict[str, float]:
    """How far two placements of one touch are apart: touch point (world units), ``node_sdf`` (cells; inf when the
    reachability or the table's shape differs), largest ``node_normal`` difference, nodes of opposite sign, samples."""
    if (a.collider is None) != (b.collider is None):
        return {"origin": float("inf"), "sdf_cells": float("inf"), "normal": 2.0, "sign_flips": 0, "samples": 0}
    out = {"origin": float((a.origin - b.origin).abs().max())}
    ca, cb = a.collider, b.collider
    if ca is None:
        return {**out, "sdf_cells": 0.0, "normal": 0.0, "sign_flips": 0, "samples": 0}
    if ca.node_sdf.shape != cb.node_sdf.shape:
        return {**out, "sdf_cells": float("inf"), "normal": 2.0, "sign_flips": 0, "samples": 0}
    return {
        **out,
        "sdf_cells": float((ca.node_sdf - cb.node_sdf).abs().max()) / dx,
        "normal": float((ca.node_normal - cb.node_normal).abs().max()),
        "sign_flips": int(((ca.node_sdf < 0) != (cb.node_sdf < 0)).sum()),
        "samples": abs(ca.n_samples - cb.n_samples),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", required=True, help="git revision to compare with (e.g. HEAD~1)")
    parser.add_argument("--objects", type=int, default=4)
    parser.add_argument("--per-object", type=int, default=10, help="touches per object (one mesh object each round)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds over all touches")
    parser.add_argument("--strict", action="store_true", help="also count the touches not placed bit-identically")
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        import_old(args.old, Path(tmp))
        import tvrecon_old.sim.press.placement as old_placement

        sim = EIPSimulator(SensorConfig(resolution=(64, 64), layers=6), PressConfig(n_grid=128))
        s, p, dev = sim.sensor, sim.cfg, sim.device
        classes = available_classes()
        objects = []  # (vertices, faces, positions, directions) per object
        for i in range(args.objects):
            mesh = make_shape(classes[(7 * i) % len(classes)], 0)
            t = sample_touches(mesh, args.per_object, seed=i, sim=sim)
            objects.append((mesh.vertices.copy(), mesh.faces.copy(), t.positions, t.directions))

        def fresh(v, f) -> trimesh.Trimesh:
            return trimesh.Trimesh(vertices=v, faces=f, process=False)  # nothing cached on it yet

        fns = {"old": old_placement.place_touch, "new": placement.place_touch}
        for f in fns.values():  # warm-up (imports, first calls) on a mesh of its own
            f(fresh(*objects[0][:2]), objects[0][2][0], objects[0][3][0], s, p, dev)
        secs = {"old": [], "new": []}
        worst = {"origin": 0.0, "sdf_cells": 0.0, "normal": 0.0, "sign_flips": 0, "samples": 0}
        differ = 0
        n = args.objects * args.per_object
        dx = 1.0 / int(p.n_grid)
        for r in range(args.repeats):
            tot = {"old": 0.0, "new": 0.0}
            for k, (v, f, positions, directions) in enumerate(objects):
                meshes = {"old": fresh(v, f), "new": fresh(v, f)}
                for j in range(args.per_object):
                    out = {}
                    for which in ("old", "new") if (k + j + r) % 2 == 0 else ("new", "old"):
                        c0 = time.process_time()
                        out[which] = fns[which](meshes[which], positions[j], directions[j], s, p, dev)
                        tot[which] += time.process_time() - c0
                    if r == 0:
                        for key, val in apart(out["old"], out["new"], dx).items():
                            worst[key] = max(worst[key], val)
                        differ += int(args.strict and not same(out["old"], out["new"]))
            for w in secs:
                secs[w].append(tot[w] / n)
            print(
                f"round {r}: old {secs['old'][-1] * 1e3:.1f} ms, new {secs['new'][-1] * 1e3:.1f} ms per touch, "
                f"old/new {secs['old'][-1] / secs['new'][-1]:.3f}"
            )
        ratios = [a / b for a, b in zip(secs["old"], secs["new"], strict=True)]
        print(
            f"old = {args.old}: {args.objects} objects x {args.per_object} touches x {args.repeats} rounds, "
            f"old/new median {statistics.median(ratios):.3f}"
            f" ({statistics.median(secs['old']) * 1e3:.1f} -> {statistics.median(secs['new']) * 1e3:.1f} ms per touch)"
        )
        print(
            f"largest differences over the {n} touches: touch point {worst['origin']:.3g} world units, node_sdf "
            f"{worst['sdf_cells']:.3g} cells, node_normal {worst['normal']:.3g}, nodes of opposite sign "
            f"{worst['sign_flips']}, surface samples {worst['samples']}"
            + (f"; not bit-identical: {differ} of {n}" if args.strict else "")
        )


if __name__ == "__main__":
    main()
