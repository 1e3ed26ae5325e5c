"""The mesh distance table before and after the distinct surface samples (2026-11-27): CPU time and error against the
exact distance, touch by touch, on the paper scene.

    OMP_NUM_THREADS=1 python -m benchmarks.probes.bench_distance_table_dedup [--exact 4]

The paper scene of ``bench_gpu.py`` (the authors' 61x61x10 pad, n_grid 128, one object's paper sweep), each touch's
collider built as ``place_batch`` builds it. ``surface_samples`` gives every triangle its own lattice, so a vertex
shared by k faces is k samples. The plain query (the table until ``CACHE_VERSION`` 6, kept here as the reference)
measured the faces of a node's 4 nearest samples, which can be 4 copies of one vertex from 4 of its faces and miss
the face that holds the nearest point; ``mesh_distance.surface_distance`` now merges the copies and measures every
face of the 4 nearest distinct points, once per (node, face), with a vectorised point-triangle distance. Prints per
touch: samples and distinct samples, the CPU seconds of each table (same process, same inputs), the nodes the plain
table read farther than the new one, and for the first ``--exact`` touches both tables' largest error against
trimesh's exact closest point (cells).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from benchmarks._common import paper_scene
from tvrecon.sim import EIPSimulator
from tvrecon.sim.bodies import mesh_distance
from tvrecon.sim.bodies.voxelize import surface_samples


def plain_distance(nodes, lo_i, dims, surface, dx, cap) -> np.ndarray:
    """The table until ``CACHE_VERSION`` 6: the faces of the 4 nearest samples (copies included), trimesh's
    closest point, each face measured once per node."""
    dist = np.full(len(nodes), cap)
    pts, fid = surface_samples(surface, spacing=dx / 2)
    near = np.flatnonzero(mesh_distance.maybe_near(pts, lo_i, dims, dx, cap))
    sd, si = cKDTree(pts).query(nodes[near], k=4, distance_upper_bound=cap)
    found = np.isfinite(sd[:, 0])
    close, sd, si = near[found], sd[found], si[found]
    cand = fid[np.minimum(si, len(pts) - 1)]
    use = np.isfinite(sd)
    for j in range(1, 4):
        use[:, j] &= ~(cand[:, j : j + 1] == cand[:, :j]).any(1)
    r, j = np.nonzero(use)
    q = nodes[close[r]]
    exact = np.full(cand.shape, np.inf)
    tris = np.asarray(surface.triangles)[cand[r, j]]
    exact[r, j] = np.linalg.norm(trimesh.triangles.closest_point(tris, q) - q, axis=1)
    dist[close] = np.minimum(exact.min(1), cap)
    return dist


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--exact", type=int, default=4, help="touches checked against trimesh's exact distance")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    sensor, press, mesh, pos, dirs, strength = paper_scene("cpu")
    calls = []
    current = mesh_distance.surface_distance

    def spy(*a):
        calls.append(a)
        return current(*a)

    mesh_distance.surface_distance = spy
    EIPSimulator(sensor, press, setup_threads=1).place_batch(mesh, pos, dirs, **strength)
    mesh_distance.surface_distance = current
    print(f"paper scene, {len(calls)} touches; CPU seconds plain -> distinct")
    total = [0.0, 0.0]
    for t, (nodes, lo_i, dims, surface, dx, cap) in enumerate(calls):
        pts, _ = surface_samples(surface, spacing=dx / 2)
        uniq = np.unique(pts, axis=0)
        t0 = time.process_time()
        old = plain_distance(nodes, lo_i, dims, surface, dx, cap)
        t1 = time.process_time()
        new, _ = current(nodes, lo_i, dims, surface, dx, cap)
        t2 = time.process_time()
        total[0] += t1 - t0
        total[1] += t2 - t1
        diff = (old - new) / dx
        line = (
            f"  touch {t}: samples {len(pts)}, distinct {len(uniq)}; {t1 - t0:.3f} -> {t2 - t1:.3f} s; nodes the plain"
            f" table read farther {np.count_nonzero(diff > 1e-9)} of {len(old)} (up to {diff.max():.3f} cells),"
            f" nearer {np.count_nonzero(diff < -1e-9)}"
        )
        if t < args.exact:
            ex = np.minimum(trimesh.proximity.closest_point(surface, nodes)[1], cap)
            e_old, e_new = np.abs(old - ex).max() / dx, np.abs(new - ex).max() / dx
            line += f"; error vs exact: plain {e_old:.4f}, distinct {e_new:.4f}"
        print(line, flush=True)
    print(f"total {total[0]:.3f} -> {total[1]:.3f} CPU-s ({total[0] / total[1]:.2f}x)")


if __name__ == "__main__":
    main()
