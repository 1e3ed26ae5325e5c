"""A touch's set-up (``placement.place_touch``: frame, touch point, mesh collider) by an earlier commit and by the
working tree, in one process (not a test).

    OMP_NUM_THREADS=1 python benchmarks/bench_setup_ab.py --old REV [--touches 20] [--repeats 3]

The older ``tvrecon`` is imported as ``tvrecon_old`` (``bench_press_ab.import_old``). Paper preset (64x64x6 pad,
n_grid 128), touch ``i`` on class ``i`` of ``available_classes()`` (wrapping), seeded cone-policy touch as in
``bench_press_ab``; each round places every touch with both versions, alternating which goes first, on one thread.
Prints the CPU milliseconds per touch of both, the old/new ratio per round and overall, and whether the collider
tables (``node_sdf``, ``node_normal``), the sample count and the touch point are bit-identical (``torch.equal``).
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_press_ab import import_old  # noqa: E402

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches import sample_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig, placement  # noqa: E402
from tvrecon.sim.sensor.pad import SensorConfig  # noqa: E402


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", required=True, help="git revision to compare with (e.g. HEAD~1)")
    parser.add_argument("--touches", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3, help="rounds over all touches")
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        import_old(args.old, Path(tmp))
        import tvrecon_old.sim.placement as old_placement

        sim = EIPSimulator(SensorConfig(resolution=(64, 64), layers=6), PressConfig(n_grid=128))
        s, p, dev = sim.sensor, sim.cfg, sim.device
        classes = available_classes()
        jobs = []
        for i in range(args.touches):
            mesh = make_shape(classes[i % len(classes)], 0)
            t = sample_touches(mesh, 1, seed=i, sim=sim)
            jobs.append((mesh, t.positions[0], t.directions[0]))
        fns = {"old": old_placement.place_touch, "new": placement.place_touch}
        for f in fns.values():  # warm-up
            f(*jobs[0], s, p, dev)
        secs = {"old": [], "new": []}
        differ = 0
        for r in range(args.repeats):
            tot = {"old": 0.0, "new": 0.0}
            for k, job in enumerate(jobs):
                out = {}
                for which in ("old", "new") if (k + r) % 2 == 0 else ("new", "old"):
                    c0 = time.process_time()
                    out[which] = fns[which](*job, s, p, dev)
                    tot[which] += time.process_time() - c0
                differ += 0 if r else int(not same(out["old"], out["new"]))
            for w in secs:
                secs[w].append(tot[w] / len(jobs))
            print(
                f"round {r}: old {secs['old'][-1] * 1e3:.1f} ms, new {secs['new'][-1] * 1e3:.1f} ms per touch, "
                f"old/new {secs['old'][-1] / secs['new'][-1]:.3f}"
            )
        ratios = [a / b for a, b in zip(secs["old"], secs["new"], strict=True)]
        print(
            f"old = {args.old}: {len(jobs)} touches x {args.repeats} rounds, "
            f"old/new median {statistics.median(ratios):.3f}"
            f" ({statistics.median(secs['old']) * 1e3:.1f} -> {statistics.median(secs['new']) * 1e3:.1f} ms per touch);"
            f" placements not bit-identical: {differ} of {len(jobs)}"
        )


if __name__ == "__main__":
    main()
