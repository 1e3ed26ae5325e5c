"""Inside / outside of many points of a watertight mesh: ``mesh.contains``, casting the second rays only where needed.

trimesh's ray-parity test (``trimesh.ray.ray_util.contains_points``, trimesh 5) casts, from every point strictly
inside the mesh's bounding box, a ray along a fixed direction and one against it (every hit counted) and decides:

- both hit counts odd: inside; both even: outside;
- counts of different parity, one of them zero: outside (a ray that meets nothing is a sure sign of free space);
- counts of different parity, both non-zero ("broken"): cast again along a random direction.

So a point whose forward ray meets nothing is outside whatever its backward ray meets. :func:`contains` casts the
forward rays first and the backward rays only from the points whose forward ray hit something: the mesh collider's
nodes above the surface (about half of them, their backward rays crossing the object) cost one ray instead of two.
Every ray is traced on its own (embree's ``rtcIntersect1`` per ray; trimesh's multi-hit loop advances each ray by
itself: offsets, stuck-ray checks and hit points are per ray), so each hit count, and each answer, is the one
``mesh.contains`` gets (``tests/sim/bodies/test_mesh_sign.py`` checks it on the shapes of the data set).
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.ray.ray_util import contains_points

__all__ = ["contains", "RAY_DIRECTION"]

#: The fixed direction of trimesh's ``contains_points`` (its ``default_direction``).
RAY_DIRECTION = np.array([0.4395064455, 0.617598629942, 0.652231566745])


def contains(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """``mesh.contains(points)`` (ray parity, trimesh 5) with the backward rays cast only where they can matter.

    Args:
        mesh: a watertight triangle mesh. points: (N, 3) float points.
    Returns:
        (N,) bool, True inside.
    """
    points = np.asanyarray(points, dtype=np.float64)
    out = np.zeros(len(points), dtype=bool)
    in_box = trimesh.bounds.contains(mesh.bounds, points)  # outside the bounding box: outside, no ray
    if not in_box.any():
        return out
    pts = points[in_box]
    dirs = np.tile(RAY_DIRECTION, (len(pts), 1))
    ray = mesh.ray
    _, idx, _ = ray.intersects_location(pts, dirs, multiple_hits=True)
    fwd = np.bincount(idx, minlength=len(pts))  # (M,) forward hits
    back = np.zeros_like(fwd)  # backward hits; left at 0 where the forward ray met nothing (outside either way)
    hit = np.flatnonzero(fwd)
    if len(hit):
        _, idx, _ = ray.intersects_location(pts[hit], -dirs[hit], multiple_hits=True)
        back[hit] = np.bincount(idx, minlength=len(hit))
    odd_f, odd_b = fwd % 2 == 1, back % 2 == 1
    agree = odd_f == odd_b
    mask = in_box.copy()
    mask[mask] = agree
    out[mask] = odd_f[agree]
    broken = ~agree & (fwd > 0) & (back > 0)
    if broken.any():  # as trimesh: once more along a random direction
        mask = in_box.copy()
        mask[mask] = broken
        direction = trimesh.util.unitize(trimesh.util.random_generator().random(3) - 0.5)
        out[mask] = contains_points(ray, pts[broken], check_direction=direction)
    return out
