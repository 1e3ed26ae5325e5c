"""Voxel carving from depth maps (works for non-watertight meshes), particles at voxel centres, occupancy SDF.

A point is solid when no view sees it as empty: for each of ``n_views`` orthographic directions spread over the
sphere, a depth map of the mesh is ray cast with trimesh (embree when available); a point in front of the first
surface along its pixel's ray (or on a ray that misses the mesh) is carved away. A closed mesh gives its solid; an
open mesh gives the visual hull its openings allow (a box with its top face removed keeps its walls and bottom and
loses the interior visible through the opening, like a cup).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy import ndimage
from torch import Tensor

from tvrecon.utils.atomic import atomic_write_bytes
from tvrecon.utils.geometry import check_mesh, perpendicular_basis
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "VoxelGrid",
    "view_directions",
    "carve_points",
    "voxelize",
    "occupancy_sdf",
    "save_particles_ply",
    "surface_samples",
]


def view_directions(n_views: int) -> np.ndarray:
    """Directions spread evenly over the unit sphere (Fibonacci lattice), always including the 6 axis directions.

    Returns:
        (V, 3) float64 unit vectors, V = n_views + 6 minus duplicates.
    """
    if n_views < 0:
        raise ValueError(f"n_views must be >= 0, got {n_views}")
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    if n_views == 0:
        return axes
    i = np.arange(n_views) + 0.5
    z = 1.0 - 2.0 * i / n_views
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = np.pi * (1.0 + 5.0**0.5) * i
    fib = np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)
    return np.concatenate([axes, fib])


def surface_samples(
    mesh: trimesh.Trimesh, spacing: float, faces: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic surface points no farther than ``spacing`` apart on every triangle (edge-adapted lattice).

    Each triangle gets the lattice ``v0 + (i / n1) e1 + (j / n2) e2`` (``i / n1 + j / n2 <= 1``) spanned by the two
    edges at its largest angle, each edge divided into steps of at most ``spacing``, plus samples every
    ``spacing`` on its longest edge. The count follows the triangle's area (a long sliver does not get the
    square of its length), and every point of the face lies within ``spacing / sqrt(2)`` of a sample.

    Args:
        mesh: triangle mesh.
        spacing: maximum distance between neighbouring samples along the lattice directions.
        faces: optional (F',) indices of the faces to sample (default all).

    Returns:
        points (S, 3) float64 and face index (S,) int64 of each point.
    """
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    fidx = np.arange(len(mesh.faces)) if faces is None else np.asarray(faces, dtype=np.int64)
    tri = np.asarray(mesh.triangles, dtype=np.float64)[fidx]  # (F', 3, 3)
    if len(tri) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    # put the vertex opposite the longest edge first: e1, e2 are then the two shorter edges
    opp = np.linalg.norm(tri[:, [2, 0, 1]] - tri[:, [1, 2, 0]], axis=2)  # (F', 3) length of the edge opposite v_k
    first = opp.argmax(1)
    order = (first[:, None] + np.arange(3)[None]) % 3
    tri = np.take_along_axis(tri, order[..., None], axis=1)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n1 = np.maximum(1, np.ceil(np.linalg.norm(e1, axis=1) / spacing)).astype(np.int64)
    n2 = np.maximum(1, np.ceil(np.linalg.norm(e2, axis=1) / spacing)).astype(np.int64)
    # rows i = 0..n1 of each triangle, row i holds j = 0..floor(n2 (1 - i / n1))
    row_tri = np.repeat(np.arange(len(tri)), n1 + 1)
    row_i = np.arange(len(row_tri)) - np.repeat(np.cumsum(n1 + 1) - (n1 + 1), n1 + 1)
    row_len = np.floor(n2[row_tri] * (1.0 - row_i / n1[row_tri]) + 1e-9).astype(np.int64) + 1
    pt_tri = np.repeat(row_tri, row_len)
    pt_i = np.repeat(row_i, row_len)
    pt_j = np.arange(len(pt_tri)) - np.repeat(np.cumsum(row_len) - row_len, row_len)
    a = (pt_i / n1[pt_tri])[:, None]
    b = (pt_j / n2[pt_tri])[:, None]
    lattice = tri[pt_tri, 0] + a * e1[pt_tri] + b * e2[pt_tri]
    # the longest edge (v1 -> v2), which the lattice only reaches at its ends
    n3 = np.maximum(1, np.ceil(opp.max(1) / spacing)).astype(np.int64)
    ed_tri = np.repeat(np.arange(len(tri)), n3 + 1)
    ed_k = np.arange(len(ed_tri)) - np.repeat(np.cumsum(n3 + 1) - (n3 + 1), n3 + 1)
    t = (ed_k / n3[ed_tri])[:, None]
    edge = tri[ed_tri, 1] + t * (tri[ed_tri, 2] - tri[ed_tri, 1])
    return np.concatenate([lattice, edge]), np.concatenate([fidx[pt_tri], fidx[ed_tri]])


def carve_points(
    mesh: trimesh.Trimesh,
    points: np.ndarray | Tensor,
    pixel: float,
    n_views: int = 26,
    tol: float | None = None,
) -> np.ndarray:
    """Solid test of query points by carving with orthographic depth maps of the mesh.

    Args:
        mesh: any triangle mesh (need not be watertight).
        points: (N, 3) query points in the mesh's coordinates.
        pixel: depth-map pixel size (e.g. half the voxel pitch).
        n_views: number of Fibonacci directions added to the 6 axis directions.
        tol: a point counts as behind the surface if its depth >= surface depth - tol (default: pixel).

    Returns:
        (N,) bool, True where no view sees the point as empty.
    """
    check_mesh(mesh)
    pts = points.detach().cpu().double().numpy() if isinstance(points, Tensor) else np.asarray(points, np.float64)
    check_shape(pts, "(N, 3)", "points")
    if not pixel > 0:
        raise ValueError(f"pixel must be > 0, got {pixel}")
    tol = pixel if tol is None else tol
    solid = np.ones(len(pts), dtype=bool)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    for d in view_directions(n_views):
        if not solid.any():
            break
        u, w = perpendicular_basis(d)
        q = pts[solid]
        s, t, z = q @ u, q @ w, q @ d
        s0, t0 = s.min() - pixel, t.min() - pixel
        ns = int(np.ceil((s.max() + pixel - s0) / pixel)) + 1
        nt = int(np.ceil((t.max() + pixel - t0) / pixel)) + 1
        ps = s0 + np.arange(ns) * pixel
        pt = t0 + np.arange(nt) * pixel
        S, T = np.meshgrid(ps, pt, indexing="ij")
        z0 = (verts @ d).min() - pixel
        origins = S.reshape(-1, 1) * u + T.reshape(-1, 1) * w + z0 * d  # (ns * nt, 3)
        dirs = np.broadcast_to(d, origins.shape)
        depth = np.full(ns * nt, np.inf)
        locs, ray_idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
        if len(ray_idx):
            np.minimum.at(depth, ray_idx, locs @ d)
        depth = depth.reshape(ns, nt)
        i_s = np.clip(np.rint((s - s0) / pixel).astype(np.int64), 0, ns - 1)
        i_t = np.clip(np.rint((t - t0) / pixel).astype(np.int64), 0, nt - 1)
        keep = z >= depth[i_s, i_t] - tol
        idx = np.flatnonzero(solid)
        solid[idx[~keep]] = False
    return solid


@dataclass
class VoxelGrid:
    """Solid occupancy of a mesh.

    occupancy: (X, Y, Z) bool numpy array.
    origin: (3,) float64 centre of voxel (0, 0, 0).
    pitch: voxel edge length.
    """

    occupancy: np.ndarray
    origin: np.ndarray
    pitch: float

    def centers(self) -> np.ndarray:
        """(P, 3) float64 centres of the solid voxels."""
        return self.origin + np.argwhere(self.occupancy) * self.pitch

    def particles(self, dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu") -> Tensor:
        """(P, 3) particle positions at the solid voxel centres."""
        return torch.as_tensor(self.centers(), dtype=dtype, device=device)

    def sdf(self) -> np.ndarray:
        """(X, Y, Z) float64 signed distance at voxel centres (< 0 inside), see ``occupancy_sdf``."""
        return occupancy_sdf(self.occupancy, self.pitch)


def voxelize(mesh: trimesh.Trimesh, pitch: float, n_views: int = 26, padding: int = 1) -> VoxelGrid:
    """Solid voxelization by carving (works for non-watertight meshes).

    Args:
        mesh: triangle mesh.
        pitch: voxel edge length in mesh units.
        n_views: carving views besides the 6 axis views.
        padding: empty voxels added around the mesh bounding box on each side.

    Returns:
        VoxelGrid whose voxel centres lie on ``origin + pitch * index``.
    """
    check_mesh(mesh)
    if not pitch > 0:
        raise ValueError(f"pitch must be > 0, got {pitch}")
    lo, hi = mesh.bounds
    dims = np.ceil((hi - lo) / pitch).astype(np.int64) + 2 * padding
    n_vox = int(np.prod(dims))
    if n_vox > 32_000_000:
        raise ValueError(f"voxel grid of {dims.tolist()} voxels is too large: increase pitch")
    origin = 0.5 * (lo + hi) - 0.5 * (dims - 1) * pitch  # grid centred on the bounding box
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in dims], indexing="ij"), -1).reshape(-1, 3)
    centers = origin + idx * pitch
    solid = carve_points(mesh, centers, pixel=0.5 * pitch, n_views=n_views, tol=0.5 * pitch).reshape(tuple(dims))
    if not mesh.is_watertight:
        # open meshes: zero-thickness walls keep the voxels they pass through, so thin shells survive carving
        pts, _ = surface_samples(mesh, spacing=pitch / 3.0)
        vi = np.clip(np.rint((pts - origin) / pitch).astype(np.int64), 0, dims - 1)
        solid[vi[:, 0], vi[:, 1], vi[:, 2]] = True
    return VoxelGrid(occupancy=solid, origin=origin, pitch=float(pitch))


def occupancy_sdf(occupancy: np.ndarray, pitch: float) -> np.ndarray:
    """Signed distance from a solid occupancy grid with scipy's exact Euclidean distance transform.

    The surface is taken half a voxel from the centres of boundary voxels: outside voxels get the distance to the
    nearest solid centre minus pitch/2, inside voxels minus (distance to the nearest empty centre minus pitch/2).

    Args:
        occupancy: (X, Y, Z) bool.
        pitch: voxel size.

    Returns:
        (X, Y, Z) float64 signed distance, < 0 inside.
    """
    occ = np.asarray(occupancy, dtype=bool)
    check_shape(occ, "(X, Y, Z)", "occupancy")
    if not occ.any():
        raise ValueError("occupancy is empty: nothing is solid")
    if occ.all():
        raise ValueError("occupancy is entirely solid: pad the grid with empty voxels")
    d_out = ndimage.distance_transform_edt(~occ) * pitch  # outside voxels: distance to nearest solid voxel
    d_in = ndimage.distance_transform_edt(occ) * pitch  # inside voxels: distance to nearest empty voxel
    return np.where(occ, -(d_in - 0.5 * pitch), d_out - 0.5 * pitch)


def save_particles_ply(path: str | Path, x: Tensor | np.ndarray) -> Path:
    """Write particles as a binary point-cloud PLY, atomically (temp file in the same folder, then os.replace).

    Args:
        path: output .ply path.
        x: (P, 3) positions.

    Returns:
        The written path.
    """
    pts = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    check_shape(pts, "(P, 3)", "x")
    return atomic_write_bytes(path, trimesh.PointCloud(pts.astype(np.float64)).export(file_type="ply"))
