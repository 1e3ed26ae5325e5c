"""Particles -> surface mesh of the deformed pad, for rendering (paper section 3.1, "Reconstruction").

The paper uses screened Poisson reconstruction; we splat the particles into a density grid (trilinear weights),
smooth it with a Gaussian (scipy) and extract the iso-surface with marching cubes (scikit-image).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.ndimage import gaussian_filter
from skimage.measure import marching_cubes
from torch import Tensor

from tvrecon.utils.shape_check import check_shape


def pad_surface(points: Tensor | np.ndarray, spacing: float, level: float = 0.5, upsample: int = 2) -> trimesh.Trimesh:
    """Surface mesh around a cloud of particles on a (deformed) lattice.

    Args:
        points: (P, 3) float32 particle positions (any frame and unit).
        spacing: rest particle spacing in the same unit as ``points``.
        level: iso level as a fraction of the density of the interior of a regular lattice (0.5 = half filled).
        upsample: voxels per particle spacing.
    Returns:
        a trimesh.Trimesh in the frame of ``points`` (outward normals).
    """
    pts = points.detach().cpu().numpy() if isinstance(points, Tensor) else np.asarray(points)
    check_shape(pts, "(P, 3)", "points")
    if len(pts) < 4:
        raise ValueError(f"points must have shape (P, 3) with P >= 4, got {tuple(pts.shape)}")
    if not np.isfinite(pts).all():
        raise ValueError("points contain NaN or infinite values")
    if not spacing > 0 or not 0 < level < 1 or int(upsample) < 1:
        raise ValueError(f"need spacing > 0, 0 < level < 1, upsample >= 1; got {spacing}, {level}, {upsample}")
    pitch = float(spacing) / int(upsample)
    lo = pts.min(0) - 3 * spacing
    dims = np.ceil((pts.max(0) + 3 * spacing - lo) / pitch).astype(int) + 1
    g = (pts - lo) / pitch  # (P, 3) voxel coordinates
    base = np.floor(g).astype(int)
    frac = g - base
    grid = np.zeros(dims, dtype=np.float64)
    for corner in range(8):  # trilinear splat
        off = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        w = np.prod(np.where(off, frac, 1.0 - frac), axis=1)
        idx = base + off
        np.add.at(grid, (idx[:, 0], idx[:, 1], idx[:, 2]), w)
    grid = gaussian_filter(grid, sigma=0.5 * int(upsample))
    interior = 1.0 / int(upsample) ** 3  # splatted mass per voxel inside a regular lattice
    verts, faces, _, _ = marching_cubes(grid, level=level * interior)
    mesh = trimesh.Trimesh(vertices=verts * pitch + lo, faces=faces[:, ::-1], process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh
