"""Capped unsigned distance from the lattice nodes of a region to a mesh surface (the size of MeshCollider's sdf).

Nearest of surface samples (spacing dx/2; scipy cKDTree, 4 neighbours within the cap), refined to the exact
distance to the faces of those samples. Two shortcuts that leave every value as it was (bit for bit):

- nodes that cannot have a sample within the cap (a distance transform of the nodes nearest to the samples, less
  half a cell diagonal) are not queried: the tree would have found nothing for them, and a query's
  answer for one point does not depend on the other points queried;
- a face found by two of a node's 4 samples is measured once (the minimum over the same set of faces).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

__all__ = ["maybe_near", "surface_distance"]


def maybe_near(pts: np.ndarray, lo_i: np.ndarray, dims: np.ndarray, dx: float, cap: float) -> np.ndarray:
    """(X * Y * Z,) bool, C order: False only where no point of ``pts`` lies within ``cap`` of the node.

    Args:
        pts: (S, 3) float64 sample points (domain units).
        lo_i: (3,) int64 global index of the region's first node (node position = index * dx).
        dims: (3,) int64 nodes per axis.
        dx: node spacing. cap: distance bound (domain units).

    Each sample is at most ``sqrt(3) / 2`` cells from its nearest node ``k``, so it is at least ``|k - i| - sqrt(3) /
    2`` cells from node ``i``: nodes whose nearest such ``k`` (a distance transform of the lattice) is farther than
    ``cap / dx + sqrt(3) / 2`` (plus a 0.01-cell slack for rounding) are certainly farther than ``cap`` from every
    sample.
    """
    dims = np.asarray(dims, dtype=np.int64)
    pad = int(np.ceil(cap / dx)) + 2
    shape = dims + 2 * pad
    # moving a node k onto the padded box only brings it closer to the region's nodes: still conservative
    c = np.clip(np.rint(pts / dx).astype(np.int64) - lo_i + pad, 0, shape - 1)
    free = np.ones(tuple(shape), dtype=bool)
    free[c[:, 0], c[:, 1], c[:, 2]] = False
    edt = distance_transform_edt(free)[pad : pad + dims[0], pad : pad + dims[1], pad : pad + dims[2]]
    return (edt <= cap / dx + 0.5 * np.sqrt(3.0) + 0.01).reshape(-1)


def surface_distance(
    nodes: np.ndarray, lo_i: np.ndarray, dims: np.ndarray, surface: trimesh.Trimesh | None, dx: float, cap: float
) -> tuple[np.ndarray, int]:
    """Distance from each node to ``surface``, capped at ``cap``.

    Args:
        nodes: (N, 3) float64 node positions, the ``dims`` lattice from global index ``lo_i`` in C order.
        lo_i: (3,) int64. dims: (3,) int64.
        surface: the mesh surface near the region (``clip_to_box``), or None (no surface: every node at ``cap``).
        dx: node spacing (samples every dx / 2). cap: distance cap (domain units).

    Returns:
        (N,) float64 distances in [0, cap] and the number of surface samples.
    """
    from tvrecon.sim.bodies.voxelize import surface_samples

    dist = np.full(len(nodes), cap)  # no surface near the node: "far"
    if surface is None:
        return dist, 0
    pts, fid = surface_samples(surface, spacing=dx / 2)
    if len(pts) == 0:
        return dist, 0
    near = np.flatnonzero(maybe_near(pts, lo_i, dims, dx, cap))
    # nodes farther than the cap only need "far": the bound keeps the query fast
    sd, si = cKDTree(pts).query(nodes[near], k=4, distance_upper_bound=cap)
    found = np.isfinite(sd[:, 0])
    close, sd, si = near[found], sd[found], si[found]
    # exact point-triangle distance to the faces of the 4 nearest samples (the samples only find them); entries
    # without a sample (inf) and faces already measured for the node are skipped
    cand = fid[np.minimum(si, len(pts) - 1)]  # (C, 4)
    use = np.isfinite(sd)
    for j in range(1, 4):
        use[:, j] &= ~(cand[:, j : j + 1] == cand[:, :j]).any(1)
    r, j = np.nonzero(use)
    q = nodes[close[r]]
    exact = np.full(cand.shape, np.inf)
    tris = np.asarray(surface.triangles)[cand[r, j]]
    exact[r, j] = np.linalg.norm(trimesh.triangles.closest_point(tris, q) - q, axis=1)
    dist[close] = np.minimum(exact.min(1), cap)
    return dist, len(pts)
