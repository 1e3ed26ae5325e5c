"""The parts of a mesh that a :class:`tvrecon.sim.bodies.colliders.MeshCollider` region needs: its surface clipped to
the region's box (the distance's samples and faces), and the node columns below the first surface seen from above (the
solid of an open mesh pressed from +z)."""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["below_first_hit", "clip_to_box"]


def clip_to_box(mesh: trimesh.Trimesh, lo: np.ndarray, hi: np.ndarray) -> trimesh.Trimesh | None:
    """The part of the surface of ``mesh`` inside the box ``[lo, hi]`` (open surface, no caps), or None if empty.

    Faces overlapping the box are cut by its six planes (``trimesh.intersections.slice_faces_plane``), so a long face
    that only crosses the box contributes only the piece inside it.

    Args:
        mesh: triangle mesh. lo, hi: (3,) box corners.
    Returns:
        a mesh of the clipped triangles (vertices (V, 3) float64, faces (F, 3) int64), or None.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    near = np.flatnonzero((tri.min(1) <= hi).all(1) & (tri.max(1) >= lo).all(1))
    if len(near) == 0:
        return None
    faces = np.asarray(mesh.faces)[near]
    used, inv = np.unique(faces, return_inverse=True)
    verts, faces = np.asarray(mesh.vertices, dtype=np.float64)[used], inv.reshape(-1, 3)
    for k in range(3):
        for sign, origin in ((1.0, lo), (-1.0, hi)):
            normal = np.zeros(3)
            normal[k] = sign
            verts, faces, _ = trimesh.intersections.slice_faces_plane(verts, faces, normal, origin)
            if len(faces) == 0:
                return None
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def below_first_hit(mesh: trimesh.Trimesh, nodes: np.ndarray, dims: np.ndarray, top: float) -> np.ndarray:
    """(N,) bool: nodes on or below the first surface met by a ray cast down (-z) from height ``top`` through them.

    One ray per node column; ``nodes`` is the (X * Y * Z, 3) lattice in C order (z fastest), shaped by ``dims``.
    """
    X, Y, Z = (int(d) for d in dims)
    cols = nodes.reshape(X, Y, Z, 3)[:, :, 0, :2].reshape(-1, 2)  # (X * Y, 2)
    origins = np.concatenate([cols, np.full((len(cols), 1), top)], axis=1)
    dirs = np.tile(np.array([0.0, 0.0, -1.0]), (len(cols), 1))
    locs, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    hit = np.full(len(cols), -np.inf)  # a column that misses the mesh is empty
    if len(ray_idx):
        np.maximum.at(hit, ray_idx, locs[:, 2])
    z = nodes[:, 2].reshape(X * Y, Z)
    return (z <= hit[:, None]).reshape(-1)
