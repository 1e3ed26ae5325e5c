"""Geometry helpers shared by the procedural shape builders.

All builders work in an arbitrary unit system and finish with :func:`finalize`, which merges the parts into one
watertight solid, centres its bounding box at the origin and scales its largest extent to 1.0.

Conventions: upright objects (bottles, cups) have their axis along +z; flat tools (fork, key, wrench) lie in the
xy plane with their thickness along z.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import trimesh
from numpy.typing import ArrayLike
from scipy.interpolate import PchipInterpolator
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

log = logging.getLogger(__name__)

SECTIONS = 48  # angular resolution of revolved and cylindrical parts


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One float drawn uniformly from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def rotation(axis: ArrayLike, angle: float) -> np.ndarray:
    """(4,4) float64 homogeneous rotation of ``angle`` radians about ``axis`` through the origin."""
    return trimesh.transformations.rotation_matrix(angle, np.asarray(axis, dtype=float))


def translation(offset: ArrayLike) -> np.ndarray:
    """(4,4) float64 homogeneous translation by ``offset`` (3,)."""
    return trimesh.transformations.translation_matrix(np.asarray(offset, dtype=float))


def moved(
    mesh: trimesh.Trimesh, *, rotate: np.ndarray | None = None, offset: ArrayLike | None = None
) -> trimesh.Trimesh:
    """Copy of ``mesh`` rotated by the (4,4) ``rotate`` (about the origin) and then translated by ``offset`` (3,)."""
    out = mesh.copy()
    if rotate is not None:
        out.apply_transform(rotate)
    if offset is not None:
        out.apply_translation(np.asarray(offset, dtype=float))
    return out


def box(extents: ArrayLike, center: ArrayLike = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Axis-aligned box with ``extents`` (3,) centred at ``center`` (3,)."""
    return moved(trimesh.creation.box(extents=np.asarray(extents, dtype=float)), offset=center)


def cylinder(
    radius: float,
    height: float,
    center: ArrayLike = (0.0, 0.0, 0.0),
    axis: ArrayLike = (0.0, 0.0, 1.0),
    sections: int = SECTIONS,
) -> trimesh.Trimesh:
    """Closed cylinder of ``radius`` and ``height`` along ``axis`` (3,), centred at ``center`` (3,)."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    return moved(mesh, rotate=_align_z(axis), offset=center)


def capsule(
    radius: float,
    length: float,
    center: ArrayLike = (0.0, 0.0, 0.0),
    axis: ArrayLike = (0.0, 0.0, 1.0),
) -> trimesh.Trimesh:
    """Capsule whose cylindrical part has ``length`` (total length ``length + 2 radius``) along ``axis``."""
    mesh = trimesh.creation.capsule(height=length, radius=radius, count=[SECTIONS // 2, SECTIONS // 2])
    return moved(mesh, rotate=_align_z(axis), offset=center)


def sphere(radius: float, center: ArrayLike = (0.0, 0.0, 0.0), subdivisions: int = 3) -> trimesh.Trimesh:
    """Icosphere of ``radius`` centred at ``center`` (3,)."""
    return moved(trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius), offset=center)


def _align_z(axis: ArrayLike) -> np.ndarray:
    """(4,4) rotation taking +z onto ``axis``."""
    a = np.asarray(axis, dtype=float)
    return trimesh.geometry.align_vectors([0.0, 0.0, 1.0], a / np.linalg.norm(a))


def smooth_curve(knots_t: ArrayLike, knots_v: ArrayLike, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Monotone-cubic (PCHIP) interpolation through knots; returns ``t`` (n,) and ``v`` (n,) float64."""
    kt = np.asarray(knots_t, dtype=float)
    kv = np.asarray(knots_v, dtype=float)
    t = np.linspace(kt[0], kt[-1], n)
    return t, PchipInterpolator(kt, kv)(t)


def lathe(profile: ArrayLike, sections: int = SECTIONS) -> trimesh.Trimesh:
    """Solid of revolution about z of a 2D profile (n,2) of (radius, z) points.

    The profile is an open polyline that starts and ends on the axis (radius 0), e.g. bottom centre -> outer wall ->
    top centre, or a closed loop that stays off the axis (a ring). The result is watertight with outward normals.
    """
    p = np.asarray(profile, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3:
        raise ValueError(f"lathe profile must be (n>=3, 2) (radius, z) points, got shape {p.shape}")
    p[:, 0] = np.maximum(p[:, 0], 0.0)
    # drop consecutive duplicates, which would create degenerate faces
    keep = np.ones(len(p), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-9
    mesh = trimesh.creation.revolve(p[keep], sections=sections)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def radial_profile(z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Closed lathe profile (n+2, 2) for a solid with outer radius ``r`` (n,) at heights ``z`` (n,), capped on the axis."""
    return np.concatenate([[[0.0, z[0]]], np.stack([r, z], axis=1), [[0.0, z[-1]]]], axis=0)


def shell_profile(z: np.ndarray, r: np.ndarray, wall: float, floor: float) -> np.ndarray:
    """Lathe profile (m, 2) of an open-top vessel (cup, bowl): outer radius ``r`` (n,) at heights ``z`` (n,) rising,
    wall thickness ``wall`` measured horizontally, solid floor of thickness ``floor`` at the bottom."""
    z0, z1 = float(z[0]), float(z[-1])
    outer = np.stack([r, z], axis=1)
    inner_mask = z >= z0 + floor
    zi = np.concatenate([[z0 + floor], z[inner_mask]])
    ri = np.interp(zi, z, r) - wall
    ri = np.maximum(ri, wall * 0.5)
    inner = np.stack([ri, zi], axis=1)[::-1]  # from the inner rim down to the floor
    return np.concatenate([[[0.0, z0]], outer, inner, [[0.0, z0 + floor]]], axis=0)


def extrude(shape: BaseGeometry, height: float, z_center: float = 0.0) -> trimesh.Trimesh:
    """Extrude a shapely Polygon (or MultiPolygon, parts are unioned) along z by ``height``, centred at ``z_center``."""
    if shape.is_empty:
        raise ValueError("cannot extrude an empty polygon")
    polys = [shape] if isinstance(shape, Polygon) else list(getattr(shape, "geoms", []))
    parts = []
    for poly in polys:
        poly = poly.buffer(0)
        if poly.is_empty or poly.area <= 0:
            continue
        mesh = trimesh.creation.extrude_polygon(poly, height)
        mesh.apply_translation([0.0, 0.0, z_center - height / 2.0])
        parts.append(mesh)
    if not parts:
        raise ValueError("polygon has no area to extrude")
    return union(parts)


def union(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean union (manifold3d engine) of watertight parts into one watertight mesh."""
    meshes = [m for m in meshes if m is not None and len(m.faces)]
    if len(meshes) == 1:
        return meshes[0].copy()
    return trimesh.boolean.union(meshes, engine="manifold")


def difference(base: trimesh.Trimesh, cutters: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean difference ``base - union(cutters)`` (manifold3d engine)."""
    return trimesh.boolean.difference([base, *cutters], engine="manifold")


def normalize(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of ``mesh`` with its bounding-box centre at the origin and its largest extent equal to 1.0."""
    out = mesh.copy()
    lo, hi = out.bounds
    extent = float(np.max(hi - lo))
    if not np.isfinite(extent) or extent <= 0:
        raise ValueError(f"cannot normalize a mesh with extent {extent}")
    out.apply_translation(-(lo + hi) / 2.0)
    out.apply_scale(1.0 / extent)
    return out


def voxel_remesh(mesh: trimesh.Trimesh, resolution: int = 96) -> trimesh.Trimesh:
    """Watertight remesh of a (possibly open or self-intersecting) mesh: voxelize at ``resolution`` cells across the
    largest extent, fill the interior, run marching cubes and smooth lightly. Returns a mesh in the input's frame."""
    extent = float(np.max(mesh.extents))
    if not np.isfinite(extent) or extent <= 0:
        raise ValueError("cannot voxel-remesh an empty or degenerate mesh")
    pitch = extent / resolution
    grid = mesh.voxelized(pitch=pitch).fill()
    dense = np.pad(grid.matrix, 1)
    from skimage import measure  # local import: scikit-image is only needed for repairs

    verts, faces, _, _ = measure.marching_cubes(dense.astype(np.float32), level=0.5)
    verts = verts - 1.0  # undo padding, index coordinates of the original grid
    verts = trimesh.transform_points(verts, grid.transform)
    out = trimesh.Trimesh(verts, faces, process=True)
    trimesh.smoothing.filter_taubin(out, iterations=5)
    _orient(out)
    return _largest_component(out)


def _orient(mesh: trimesh.Trimesh) -> None:
    trimesh.repair.fix_normals(mesh)
    if mesh.volume < 0:
        mesh.invert()


def _largest_component(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    return max(parts, key=lambda m: abs(m.volume))


def finalize(parts: trimesh.Trimesh | Sequence[trimesh.Trimesh], name: str = "shape") -> trimesh.Trimesh:
    """Union the parts, check watertightness (voxel remesh fallback), orient outwards and normalize to the unit box."""
    mesh = union(parts if isinstance(parts, Sequence) else [parts])
    mesh.merge_vertices()
    mesh.remove_unreferenced_vertices()
    if not mesh.is_watertight or mesh.body_count != 1:
        log.warning(
            "shape %r: union gave %d bodies, watertight=%s; voxel remesh", name, mesh.body_count, mesh.is_watertight
        )
        mesh = voxel_remesh(mesh)
    _orient(mesh)
    if not mesh.is_watertight or mesh.volume <= 0:
        raise RuntimeError(f"shape {name!r} is not a watertight solid after repair")
    return normalize(mesh)
