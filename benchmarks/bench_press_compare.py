"""Paper-preset touches through the press path before and after issue 13 step 3, in one process (not a test).

    OMP_NUM_THREADS=1 python benchmarks/bench_press_compare.py [--touches 6] [--first 0] [--repeats 1]

Each touch (one class of ``available_classes()`` each, from ``--first``, seeded cone-policy touch) is pressed with the
paper preset (64x64x6 pad, n_grid 128) by the current code ("new") and by the code it replaced ("old", benchmark-only
copies below patched in), alternating which goes first, on one thread. Prints per touch the CPU seconds of both, their
ratio, and whether the two readings are bit-identical (every field, ``torch.equal``); then the median and the total
ratio. Absolute seconds depend on the machine's load; only the ratio measured in the same process means something.

What "old" restores: the per-step ``scatter_reduce`` bounds and ``batch.max()`` of the block layout
(``MLSMPM._scenes`` -> no block), and the collider asked node by node (``MeshCollider.at_nodes`` on an (nb, 3) lattice
built every step, normals renormalized after each gather, the one-scene grid copied by ``torch.cat``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim import mpm  # noqa: E402
from tvrecon.sim.bodies.colliders import MeshCollider
from tvrecon.sim.bodies.grid_contact import collide_grid  # noqa: E402
from tvrecon.sim.mpm import MLSMPM  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402

FIELDS = ("image", "position", "direction", "steps", "depth", "chamfer", "force", "contact", "force_field")


def _old_scenes(self, batch):
    """Before: the scene count from ``batch.max()`` every step and no block size (scatter_reduce bounds)."""
    return (1 if batch is None else int(batch.max()) + 1), None


def _old_at_nodes(self, index):
    """Before: ``MeshCollider.at_nodes`` renormalizing the gathered normals on every call."""
    dev = index.device
    g = index - self.lo_index.to(device=dev, dtype=torch.long)
    hi = torch.tensor([d - 1 for d in self.dims], device=dev)
    gc = torch.minimum(torch.clamp(g, min=0), hi)
    flat = (gc[:, 0] * self.dims[1] + gc[:, 1]) * self.dims[2] + gc[:, 2]
    sdf_t = self.node_sdf.to(dev).reshape(-1)
    nrm_t = self.node_normal.to(dev).reshape(-1, 3)
    outside = (g - gc).to(torch.float32).norm(dim=1) * self.dx
    n = nrm_t[flat]
    nn = n.norm(dim=1, keepdim=True)
    up = torch.zeros_like(n)
    up[:, 2] = 1.0
    n = torch.where(nn > 1e-12, n / torch.where(nn > 1e-12, nn, torch.ones_like(nn)), up)
    return sdf_t[flat] + outside, n


def _old_collide_grid(gv, gm, colliders, *args, **kwargs):
    """Before: ``torch.cat`` copied the grid velocity and node forces even for one scene."""
    v, force, node_force = collide_grid(gv, gm, colliders, *args, **kwargs)
    if len(colliders) == 1 and any(c is not None for c in colliders):
        return torch.cat([v], 0), force, torch.cat([node_force], 0)
    return v, force, node_force


@contextmanager
def old_path():
    """Patch the replaced code back in for the duration."""
    saved = MLSMPM._scenes, MeshCollider.at_block, MeshCollider.at_nodes, mpm.collide_grid
    MLSMPM._scenes = _old_scenes
    del MeshCollider.at_block  # collide_grid falls back to at_nodes on the (nb, 3) node lattice
    MeshCollider.at_nodes = _old_at_nodes
    mpm.collide_grid = _old_collide_grid
    try:
        yield
    finally:
        MLSMPM._scenes, MeshCollider.at_block, MeshCollider.at_nodes, mpm.collide_grid = saved


def same(a, b) -> bool:
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, torch.Tensor):
            if not (isinstance(y, torch.Tensor) and x.dtype == y.dtype and torch.equal(x, y)):
                return False
        elif x != y:
            return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--touches", type=int, default=6, help="touches, one class each")
    parser.add_argument("--first", type=int, default=0, help="index of the first class")
    parser.add_argument("--repeats", type=int, default=1, help="old/new pairs per touch")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sim = EIPSimulator(SensorConfig(resolution=(64, 64), layers=6), PressConfig(n_grid=128))
    classes = available_classes()
    names = [classes[(args.first + i) % len(classes)] for i in range(args.touches)]
    jobs = []
    for i, name in enumerate(names):
        mesh = make_shape(name, 0)
        t = sample_touches(mesh, 1, seed=i, sim=sim)
        jobs.append((name, mesh, t.positions[0], t.directions[0], t.strengths[0]))
    name, mesh, pos, d, kw = jobs[0]
    sim.press(mesh, pos, d, **kw)  # warm-up
    print(f"torch {torch.__version__}, 1 thread, paper preset: 64x64x6 pad, n_grid 128; {len(jobs)} touches")
    ratios, tot_old, tot_new, all_same = [], 0.0, 0.0, True
    for k, (name, mesh, pos, d, kw) in enumerate(jobs):
        t_old, t_new = [], []
        for r in range(args.repeats):
            for which in ("old", "new") if (k + r) % 2 == 0 else ("new", "old"):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    c0 = time.process_time()
                    if which == "old":
                        with old_path():
                            ro = sim.press(mesh, pos, d, **kw)
                        t_old.append(time.process_time() - c0)
                    else:
                        rn = sim.press(mesh, pos, d, **kw)
                        t_new.append(time.process_time() - c0)
        o, n = statistics.median(t_old), statistics.median(t_new)
        eq = same(ro, rn)
        all_same &= eq
        ratios.append(o / n)
        tot_old, tot_new = tot_old + o, tot_new + n
        print(f"{name:14s} steps {rn.steps:4d} old {o:6.2f} CPU-s new {n:6.2f} CPU-s old/new {o / n:5.3f} equal {eq}")
    print(
        f"median old/new {statistics.median(ratios):.3f}, total old/new {tot_old / tot_new:.3f} "
        f"({tot_old / len(jobs):.2f} -> {tot_new / len(jobs):.2f} CPU-s per touch on this machine's load); "
        f"readings bit-identical: {all_same}"
    )


if __name__ == "__main__":
    main()
