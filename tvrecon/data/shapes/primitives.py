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

from tvrecon.utils.shape_check import check_shape

log = logging.getLogger(__name__)

SECTIONS = 48  # angular resolution of revolved and cylindrical parts


def signed_volume(mesh: trimesh.Trimesh) -> float:
    """Signed enclosed volume (divergence theorem), cheaper than ``mesh.volume`` (no inertia tensor)."""
    tri = mesh.vertices[mesh.faces]  # (F, 3, 3)
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One float drawn uniformly from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def rotation(axis: ArrayLike, angle: float) -> np.ndarray:
    """(4,4) float64 homogeneous rotation of ``angle`` radians about ``axis`` through the origin."""
    return trimesh.transformations.rotation_matrix(angle, np.asarray(axis, dtype=float))


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
    check_shape(p, "(n, 2)", "lathe profile")
    if len(p) < 3:
        raise ValueError(f"lathe profile must have shape (n, 2) with n >= 3 (radius, z) points, got {p.shape}")
    p[:, 0] = np.maximum(p[:, 0], 0.0)
    # drop consecutive duplicates, which would create degenerate faces
    keep = np.ones(len(p), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(p, axis=0), axis=1) > 1e-9
    mesh = trimesh.creation.revolve(p[keep], sections=sections)
    if signed_volume(mesh) < 0:
        mesh.invert()
    return mesh


def radial_profile(z: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Lathe profile (n+2, 2) of a solid with outer radius ``r`` (n,) at heights ``z`` (n,), closed on the axis."""
    return np.concatenate([[[0.0, z[0]]], np.stack([r, z], axis=1), [[0.0, z[-1]]]], axis=0)


def _crossing(p: np.ndarray, q: np.ndarray, coord: int, value: float) -> np.ndarray:
    t = (value - p[coord]) / (q[coord] - p[coord])
    return p + t * (q - p)


def vessel(
    r: np.ndarray, z: np.ndarray, thickness: float, sections: int = SECTIONS
) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """Open-top vessel (bowl, cup, plate) from its outer profile (a vertical lip of height ``thickness`` is added).

    ``r`` (n,) and ``z`` (n,) trace the outer surface from the bottom centre (r[0] = 0) to the rim, both
    non-decreasing. The inner surface is the outer one shifted by (-thickness, +thickness) in (r, z), which keeps a
    normal wall thickness >= ``thickness`` everywhere and can never self-intersect. Returns (shell, cavity): the
    watertight vessel and the watertight solid of its inner space extended above the rim (to cut handles with).
    """
    outer = np.stack([np.asarray(r, dtype=float), np.asarray(z, dtype=float)], axis=1)
    if outer[0, 0] != 0.0 or np.any(np.diff(outer, axis=0) < -1e-12):
        raise ValueError("vessel profile must start on the axis (r[0] == 0) with non-decreasing r and z")
    # vertical lip of one wall thickness: the rim is then a flat ring of width `thickness`, never a knife edge
    outer = np.concatenate([outer, [[outer[-1, 0], outer[-1, 1] + thickness]]], axis=0)
    h = outer[-1, 1]
    inner = outer + np.array([-thickness, thickness])
    i = int(np.argmax(inner[:, 0] > 0))
    j = int(np.nonzero(inner[:, 1] < h)[0][-1])
    if i == 0 or j <= i or inner[-1, 1] <= h:
        raise ValueError("vessel is too thin or too shallow for the requested wall thickness")
    start = _crossing(inner[i - 1], inner[i], 0, 0.0)
    end = _crossing(inner[j], inner[j + 1], 1, h)
    inner_curve = np.concatenate([[start], inner[i : j + 1], [end]], axis=0)
    shell = lathe(np.concatenate([outer, inner_curve[::-1]], axis=0), sections=sections)
    top = h + 10.0 * thickness + 1.0
    cavity_profile = np.concatenate([inner_curve, [[end[0], top], [0.0, top]]], axis=0)
    cavity = lathe(cavity_profile, sections=sections)
    return shell, cavity


def tube(
    path: ArrayLike, radii: ArrayLike, sides: int = 24, lobes: int = 0, lobe_depth: float = 0.0
) -> trimesh.Trimesh:
    """Watertight tube along a 3D polyline ``path`` (n,3) with per-point ``radii`` (n,), flat-capped at both ends.

    Cross-sections are circles (or ``lobes``-fold rounded polygons, radius modulated by ``lobe_depth``), framed by
    parallel transport. The path's curvature radius must exceed the tube radius.
    """
    p = np.asarray(path, dtype=float)
    rad = np.asarray(radii, dtype=float)
    check_shape(p, "(n, 3)", "tube path")
    if len(p) < 2 or rad.shape != (len(p),):
        raise ValueError(f"tube path must have shape (n, 3) with n >= 2 and radii (n,), got {p.shape} and {rad.shape}")
    tang = np.gradient(p, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    ref = np.array([0.0, 0.0, 1.0]) if abs(tang[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    normal = np.cross(tang[0], ref)
    normal /= np.linalg.norm(normal)
    normals = [normal]
    for k in range(1, len(p)):
        n = normals[-1] - np.dot(normals[-1], tang[k]) * tang[k]
        normals.append(n / np.linalg.norm(n))
    nrm = np.array(normals)
    bin_ = np.cross(tang, nrm)
    theta = np.linspace(0.0, 2 * np.pi, sides, endpoint=False)
    shape = 1.0 + lobe_depth * np.cos(lobes * theta) if lobes else np.ones(sides)
    ring = (np.cos(theta) * shape)[None, :, None] * nrm[:, None, :] + (np.sin(theta) * shape)[None, :, None] * bin_[
        :, None, :
    ]
    verts = (p[:, None, :] + rad[:, None, None] * ring).reshape(-1, 3)
    n, m = len(p), sides
    faces = []
    for k in range(n - 1):
        a = k * m + np.arange(m)
        b = k * m + (np.arange(m) + 1) % m
        faces += np.stack([a, b, b + m], axis=1).tolist() + np.stack([a, b + m, a + m], axis=1).tolist()
    c0, c1 = len(verts), len(verts) + 1
    verts = np.concatenate([verts, p[:1], p[-1:]], axis=0)
    ar = np.arange(m)
    faces += np.stack([np.full(m, c0), (ar + 1) % m, ar], axis=1).tolist()
    last = (n - 1) * m
    faces += np.stack([np.full(m, c1), last + ar, last + (ar + 1) % m], axis=1).tolist()
    mesh = trimesh.Trimesh(verts, np.asarray(faces), process=True)
    if signed_volume(mesh) < 0:
        mesh.invert()
    return mesh


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


def refine(mesh: trimesh.Trimesh, max_edge: float) -> trimesh.Trimesh:
    """Crack-free subdivision (manifold3d ``refine_to_length``) so that no edge is longer than ``max_edge``."""
    import manifold3d

    man = manifold3d.Manifold(
        manifold3d.Mesh(
            vert_properties=np.asarray(mesh.vertices, dtype=np.float32),
            tri_verts=np.asarray(mesh.faces, dtype=np.uint32),
        )
    )
    if man.status() != manifold3d.Error.NoError:
        raise ValueError(f"refine needs a watertight manifold mesh, manifold3d says {man.status()}")
    out = man.refine_to_length(max_edge).to_mesh()
    return trimesh.Trimesh(
        np.asarray(out.vert_properties[:, :3], dtype=np.float64), np.asarray(out.tri_verts), process=False
    )


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


def voxel_remesh(mesh: trimesh.Trimesh, resolution: int = 64) -> trimesh.Trimesh:
    """Watertight remesh of a (possibly open or self-intersecting) mesh: voxelize at ``resolution`` cells across the
    largest extent, fill the enclosed interior, run marching cubes and smooth lightly; keep the largest part.
    An open surface that encloses nothing becomes a thin (about one voxel) solid shell. Returns a mesh in the input's
    frame."""
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
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_normals(mesh)
    if signed_volume(mesh) < 0:
        mesh.invert()


def _largest_component(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    if mesh.body_count <= 1:
        return mesh
    parts = mesh.split(only_watertight=False)
    if len(parts) <= 1:
        return mesh
    return max(parts, key=lambda m: abs(m.volume))


def finalize(parts: trimesh.Trimesh | Sequence[trimesh.Trimesh], name: str = "shape") -> trimesh.Trimesh:
    """Union the parts, check watertightness (voxel remesh fallback), orient outwards and normalize to the unit box."""
    mesh = union(parts if isinstance(parts, Sequence) else [parts])
    # no merge_vertices here: manifold3d output is already indexed, and merging close vertices can break manifoldness
    if not mesh.is_watertight or mesh.body_count != 1:
        log.warning(
            "shape %r: union gave %d bodies, watertight=%s; voxel remesh", name, mesh.body_count, mesh.is_watertight
        )
        mesh = voxel_remesh(mesh)
    _orient(mesh)
    if not mesh.is_watertight or signed_volume(mesh) <= 0:
        raise RuntimeError(f"shape {name!r} is not a watertight solid after repair")
    return normalize(mesh)
