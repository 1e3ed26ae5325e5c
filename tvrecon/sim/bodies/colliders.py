"""Rigid static colliders as signed distance functions in unit-domain coordinates (sdf < 0 inside).

``SphereCollider`` and ``PlaneCollider`` are analytic. ``MeshCollider`` precomputes the signed distance of a trimesh
mesh on the lattice nodes of a region (the nodes a sensor can reach) and looks it up trilinearly.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.sim.bodies.mesh_region import below_first_hit, clip_to_box
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "Collider",
    "SphereCollider",
    "PlaneCollider",
    "MeshCollider",
    "OPEN_SHELL_CELLS",
    "unit_or_up",
    "unit_toward",
]

#: Half-thickness, in grid cells, of the shell an open (non-watertight) mesh is given by ``MeshCollider`` without
#: ``from_above``: its carved solid is grown by this much, so a zero-thickness wall becomes a plate 2 cells thick.
#: One cell is the least that always holds a connected layer of grid nodes whatever the wall's tilt (a slab thinner
#: than sqrt(3) cells can fall between the nodes along a diagonal) and keeps the walls as thin as the grid resolves.
OPEN_SHELL_CELLS = 1.0


@runtime_checkable
class Collider(Protocol):
    """A rigid, static body: signed distance (< 0 inside) and unit outward normal at query points."""

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) float points -> (N,) signed distance, < 0 inside."""
        ...

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) float points -> (N, 3) unit outward normal (gradient of the sdf)."""
        ...


def _check_points(points: Tensor) -> None:
    if not isinstance(points, Tensor):
        raise ValueError(f"points must be an (N, 3) tensor, got {type(points).__name__}")
    check_shape(points, "(N, 3)", "points")


def _vec3(value: Sequence[float] | Tensor | np.ndarray, name: str) -> Tensor:
    t = torch.as_tensor(np.asarray(value, dtype=np.float64) if not isinstance(value, Tensor) else value)
    check_shape(t, "(3,)", name)
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {t.tolist()}")
    return t


class SphereCollider:
    """Solid sphere.

    Args:
        center: (3,) centre in domain units.
        radius: radius > 0 in domain units.
    """

    def __init__(self, center: Sequence[float] | Tensor, radius: float) -> None:
        self.center = _vec3(center, "center")
        if not float(radius) > 0:
            raise ValueError(f"radius must be > 0, got {radius}")
        self.radius = float(radius)

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N,) ``|p - c| - r``."""
        _check_points(points)
        return (points - self.center.to(points)).norm(dim=1) - self.radius

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N, 3) unit ``(p - c) / |p - c|`` (+z at the centre itself)."""
        _check_points(points)
        d = points - self.center.to(points)
        n = d.norm(dim=1, keepdim=True)
        up = torch.zeros_like(d)
        up[:, 2] = 1.0
        return torch.where(n > 0, d / torch.where(n > 0, n, torch.ones_like(n)), up)


class PlaneCollider:
    """Half-space below a plane: solid where ``(p - point) . normal < 0``.

    Args:
        point: (3,) a point on the plane.
        normal: (3,) outward normal (normalized here; must be non-zero).
    """

    def __init__(self, point: Sequence[float] | Tensor, normal: Sequence[float] | Tensor) -> None:
        self.point = _vec3(point, "point")
        n = _vec3(normal, "normal").to(torch.float64)
        norm = float(n.norm())
        if norm < 1e-12:
            raise ValueError("normal must be non-zero")
        self.n = n / norm

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N,) ``(p - point) . n``."""
        _check_points(points)
        return ((points - self.point.to(points)) * self.n.to(points)).sum(1)

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N, 3) the constant plane normal."""
        _check_points(points)
        return self.n.to(points).expand(points.shape[0], 3).clone()


class MeshCollider:
    """Rigid mesh as a signed distance field sampled on the lattice nodes of a region, looked up trilinearly.

    Sign: ``mesh.contains`` (ray parity, embree; cast by :func:`.mesh_sign.contains`) for watertight meshes. An open
    mesh (an open box, a single plane, a mesh with a hole) has no inside, and a zero-thickness wall has no grid node
    inside it; it is made solid in one of two ways:

    - ``from_above=True`` (the press: bodies come from +z): solid is what lies behind the first surface seen from
      above, in a depth map of one ray per node column cast down from the region's top (a sheet is as thick as the
      region is deep, and the holes of a mesh stay holes). This is the carving of ``voxelize.carve_points`` with the
      one view the pad has; a closed mesh gives the same solid, so open and closed meshes press alike.
    - otherwise: voxel carving from depth maps over ``n_views`` directions (``voxelize.carve_points``), grown by
      ``OPEN_SHELL_CELLS`` (sdf minus ``offset``), so a wall seen from both sides becomes a shell 2 cells thick with
      grid nodes inside it (a body coming from either side is stopped while it stays within the shell).

    Unsigned distance (:mod:`.mesh_distance`): nearest of surface samples (spacing dx/2,
    on the surface clipped to the region box grown by the 4-cell distance cap; scipy cKDTree), refined
    to the exact distance to the faces of the 4 nearest samples. Normal: central-difference gradient of the node sdf.

    Args:
        mesh: trimesh mesh already in domain coordinates.
        n_grid: cells across the unit domain (node spacing dx = 1 / n_grid).
        region: (lo (3,), hi (3,)) domain-coordinate box whose lattice nodes get the sdf; None = mesh bounds + 3 cells.
        device: device of the node tables (sdf/normal follow the query points' device and dtype).
        n_views: carving views for open meshes (without ``from_above``).
        from_above: open meshes are solid behind their first surface seen from +z (see above); no effect on
            watertight meshes.
        watertight: ``mesh.is_watertight`` when the caller knows it (a mesh with the same faces), else None.
        sign_frame: the same object in another frame, ``(source, rotation (3, 3), origin (3,), scale)`` with
            ``source`` vertex = ``origin + scale * rotation @ mesh vertex`` (``source`` has ``mesh``'s faces): a
            watertight mesh's inside test casts its rays in that frame, on ``source``'s ray intersector, which
            trimesh builds once per mesh object (the press: the object's own mesh, shared by its touches, against
            a new domain-frame mesh and Embree scene per touch). None: on ``mesh``.

    Attributes:
        offset: how far (domain units) the collider's surface lies outside the mesh's surface: ``OPEN_SHELL_CELLS *
            dx`` for an open mesh without ``from_above``, else 0.

    Points outside the region get the sdf of the nearest region point plus their distance to the region box.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        n_grid: int = 128,
        region: tuple[Sequence[float], Sequence[float]] | None = None,
        device: str | torch.device = "cpu",
        n_views: int = 26,
        from_above: bool = False,
        watertight: bool | None = None,
        sign_frame: tuple[trimesh.Trimesh, np.ndarray, np.ndarray, float] | None = None,
    ) -> None:
        from tvrecon.sim.bodies.mesh_distance import surface_distance
        from tvrecon.sim.bodies.mesh_sign import contains
        from tvrecon.sim.bodies.voxelize import carve_points
        from tvrecon.utils.geometry import check_mesh

        check_mesh(mesh)
        if n_grid < 4:
            raise ValueError(f"n_grid must be >= 4, got {n_grid}")
        dx = 1.0 / n_grid
        if region is None:
            lo_pt, hi_pt = mesh.bounds[0] - 3 * dx, mesh.bounds[1] + 3 * dx
        else:
            lo_pt, hi_pt = (np.asarray(r, dtype=np.float64) for r in region)
            check_shape(lo_pt, "(3,)", "region lo")
            check_shape(hi_pt, "(3,)", "region hi")
            if not (hi_pt >= lo_pt).all():
                raise ValueError(f"region must be (lo (3,), hi (3,)) with hi >= lo, got {region}")
        lo_i = np.floor(lo_pt / dx).astype(np.int64)
        hi_i = np.ceil(hi_pt / dx).astype(np.int64)
        dims = hi_i - lo_i + 1
        if int(np.prod(dims)) > 16_000_000:
            raise ValueError(f"region spans {dims.tolist()} nodes: give a smaller region (the nodes the pad can reach)")
        axes = [np.arange(lo_i[k], hi_i[k] + 1) * dx for k in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)  # (N, 3)

        # unsigned distance from surface samples of the faces near the region, clipped to the region box grown by
        # the distance cap: only surface within `margin` of a node can be its nearest sample below the cap, so the
        # sample count follows the region, not the length of the faces crossing it
        margin = 4 * dx
        clipped = clip_to_box(mesh, lo_i * dx - margin, hi_i * dx + margin)
        dist, self.n_samples = surface_distance(nodes, lo_i, dims, clipped, dx, margin)
        self.offset = 0.0
        if mesh.is_watertight if watertight is None else watertight:
            if sign_frame is None:
                inside = contains(mesh, nodes)  # mesh.contains, fewer rays
            else:
                source, rotation, origin, scale = sign_frame
                rotation, origin = np.asarray(rotation, dtype=np.float64), np.asarray(origin, dtype=np.float64)
                check_shape(rotation, "(3, 3)", "sign_frame rotation")
                check_shape(origin, "(3,)", "sign_frame origin")
                inside = contains(source, origin + float(scale) * nodes @ rotation.T)
            sdf = np.where(inside, -dist, dist)
        elif from_above:
            sdf = np.where(below_first_hit(mesh, nodes, dims, top=hi_i[2] * dx + margin), -dist, dist)
        else:
            # a wall seen from both sides is carved away and would be solid nowhere: grow the carved solid
            self.offset = OPEN_SHELL_CELLS * dx
            inside = carve_points(mesh, nodes, pixel=0.5 * dx, n_views=n_views, tol=0.5 * dx)
            sdf = np.where(inside, -dist, dist) - self.offset
        sdf = sdf.reshape(tuple(dims))
        grad = np.stack(np.gradient(sdf, dx), -1)  # (X, Y, Z, 3)
        gn = np.linalg.norm(grad, axis=-1, keepdims=True)
        grad = np.where(gn > 1e-12, grad / np.maximum(gn, 1e-12), np.array([0.0, 0.0, 1.0]))
        self.dx = dx
        self.dims = tuple(int(d) for d in dims)
        self.lo_index = torch.as_tensor(lo_i, dtype=torch.float64, device=device)
        self.lo = torch.as_tensor(lo_i * dx, dtype=torch.float64, device=device)
        self.hi = torch.as_tensor(hi_i * dx, dtype=torch.float64, device=device)
        self.node_sdf = torch.as_tensor(sdf, dtype=torch.float32, device=device)  # (X, Y, Z)
        self.node_normal = torch.as_tensor(grad, dtype=torch.float32, device=device)  # (X, Y, Z, 3)

    def to(self, device: str | torch.device) -> MeshCollider:
        """This collider with its tables on ``device`` (a copy; ``self`` when they are there already): the same
        values, e.g. a collider built on the CPU by a set-up process (:mod:`tvrecon.sim.press.setup_pool`)."""
        device = torch.device(device)
        if self.node_sdf.device == device or (device.index is None and self.node_sdf.device.type == device.type):
            return self
        out = copy.copy(self)
        for name, value in vars(self).items():
            if isinstance(value, Tensor):
                setattr(out, name, value.to(device))
        return out

    def _cell(self, points: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(N, 3) points -> the (N, 3) int64 table indices of the lower and upper corners of their trilinear cell
        (clamped to the table) and the (N, 3) float64 position within it."""
        X, Y, Z = self.dims
        g = points.double() / self.dx - self.lo_index.to(points.device)
        hi = torch.tensor([X - 1, Y - 1, Z - 1], dtype=torch.float64, device=points.device)
        g = torch.minimum(torch.clamp(g, min=0.0), hi)
        i0 = torch.minimum(torch.floor(g), torch.clamp(hi - 1, min=0)).long()
        return i0, torch.minimum(i0 + 1, hi.long()), g - i0

    def count_inside(self, points: Tensor) -> int:
        """``int((self.sdf(points) < 0).sum())`` for (N, 3) points, without interpolating when no table node of the
        cells spanned by their bounding box is negative: :meth:`sdf` is a trilinear combination (weights in [0, 1]) of
        a cell's 8 nodes plus a distance >= 0, and the cell index is monotone in each coordinate."""
        _check_points(points)
        lo, hi, _ = self._cell(torch.stack([points.min(0).values, points.max(0).values]))  # (2, 3) each
        (a0, a1, a2), (b0, b1, b2) = lo[0].tolist(), hi[1].tolist()
        if bool((self.node_sdf[a0 : b0 + 1, a1 : b1 + 1, a2 : b2 + 1] >= 0).all()):
            return 0
        return int((self.sdf(points) < 0).sum())

    def near(self, points: Tensor, reach: float) -> Tensor:
        """(N, 3) points -> (N,) bool, True for every point with ``sdf(points) < reach`` (and maybe a few more).

        :meth:`sdf` is a trilinear combination (weights in [0, 1]) of its cell's 8 nodes plus a distance >= 0, so it is
        at least the least of the 8; one gather of that least value per point (a table of cell minima, built once)
        rules out the points far from the body without interpolating (the particle contact asks every step)."""
        _check_points(points)
        cmin = self.cell_min(points.device)  # (X', Y', Z')
        top = torch.tensor(cmin.shape, device=points.device) - 1
        g = points.float() / self.dx - self.lo_index.to(device=points.device, dtype=torch.float32)
        i0 = torch.minimum(torch.clamp(torch.floor(g), min=0).long(), top)  # _cell's lower corner, in float32
        least = cmin[i0[:, 0], i0[:, 1], i0[:, 2]]
        # margins: the float32 round-off of the interpolation, and a point float32 puts in a neighbouring cell
        return least - 1e-5 * least.abs() - 1e-3 * self.dx < reach

    def cell_min(self, device: torch.device) -> Tensor:
        """(max(X - 1, 1), ...) float32 least node sdf of each trilinear cell (``_cell``'s lower corner), per device."""
        cache = self.__dict__.setdefault("_cell_min_cache", {})
        if device not in cache:
            m = self.node_sdf.to(device)
            for axis in range(3):
                if m.shape[axis] > 1:
                    m = torch.minimum(m.narrow(axis, 0, m.shape[axis] - 1), m.narrow(axis, 1, m.shape[axis] - 1))
            cache[device] = m.contiguous()
        return cache[device]

    def _lookup(self, table: Tensor, points: Tensor) -> Tensor:
        """Trilinear interpolation of a (X, Y, Z, C) node table at (N, 3) points -> (N, C)."""
        i0, i1, f = self._cell(points)
        f = f.to(points.dtype)
        t = table.to(device=points.device, dtype=points.dtype)
        terms = []  # corner c = (cx, cy, cz), cx slowest
        for cx in (0, 1):
            ix = i1[:, 0] if cx else i0[:, 0]
            wx = f[:, 0] if cx else 1 - f[:, 0]
            for cy in (0, 1):
                iy = i1[:, 1] if cy else i0[:, 1]
                wy = f[:, 1] if cy else 1 - f[:, 1]
                for cz in (0, 1):
                    iz = i1[:, 2] if cz else i0[:, 2]
                    wz = f[:, 2] if cz else 1 - f[:, 2]
                    terms.append((wx * wy * wz)[:, None] * t[ix, iy, iz])
        return corner_sum(torch.stack(terms, 1))

    def _unit_normals(self, device: torch.device) -> Tensor:
        """(X * Y * Z, 3) float32 node normals renormalized in float32 (+z where zero), once per device."""
        cache = self.__dict__.setdefault("_unit_normal_cache", {})
        if device not in cache:
            n = self.node_normal.to(device).reshape(-1, 3)
            nn = n.norm(dim=1, keepdim=True)
            up = torch.zeros_like(n)
            up[:, 2] = 1.0
            cache[device] = torch.where(nn > 1e-12, n / torch.where(nn > 1e-12, nn, torch.ones_like(nn)), up)
        return cache[device]

    def at_nodes(self, index: Tensor) -> tuple[Tensor, Tensor]:
        """Signed distance and unit normal at integer lattice nodes, by direct gather (no interpolation).

        Equal to ``sdf(index * dx)`` and ``normal(index * dx)`` (a lattice node is a table node, or is clamped to
        the nearest one plus its distance to the region box), at a fraction of the cost: the MPM grid asks for its
        nodes every step.

        Args:
            index: (N, 3) int64 global node indices (node position = index * dx).
        Returns:
            sdf (N,) float32 and normal (N, 3) float32 on ``index.device``.
        """
        dev = index.device
        g = index - self.lo_index.to(device=dev, dtype=torch.long)
        hi = torch.tensor([d - 1 for d in self.dims], device=dev)
        gc = torch.minimum(torch.clamp(g, min=0), hi)
        flat = (gc[:, 0] * self.dims[1] + gc[:, 1]) * self.dims[2] + gc[:, 2]
        sdf_t = self.node_sdf.to(dev).reshape(-1)
        outside = (g - gc).to(torch.float32).norm(dim=1) * self.dx
        return sdf_t[flat] + outside, self._unit_normals(dev)[flat]

    def at_block(
        self, lo: Sequence[int], D: Sequence[int], device: str | torch.device = "cpu"
    ) -> tuple[Tensor, Tensor]:
        """:meth:`at_nodes` of a whole block: the ``D[0] x D[1] x D[2]`` nodes from global node ``lo``, i slowest.

        Same values as ``at_nodes`` of those nodes; the flat table index is built from three per-axis index vectors
        and the distance to the region box only when the block leaves it (the MPM grid asks every step).

        Returns:
            sdf (N,) float32 and normal (N, 3) float32 on ``device``, N = D[0] * D[1] * D[2].
        """
        dev = torch.device(device)
        lo_t = self.__dict__.get("_lo_int")
        if lo_t is None:
            lo_t = self._lo_int = [int(v) for v in self.lo_index.round().long().tolist()]
        g = [torch.arange(int(lo[k]) - lo_t[k], int(lo[k]) - lo_t[k] + int(D[k]), device=dev) for k in range(3)]
        gc = [g[k].clamp(0, self.dims[k] - 1) for k in range(3)]
        flat = (gc[0][:, None, None] * self.dims[1] + gc[1][None, :, None]) * self.dims[2] + gc[2][None, None, :]
        flat = flat.reshape(-1)
        sdf = self.node_sdf.to(dev).reshape(-1)[flat]
        inside = all(int(lo[k]) >= lo_t[k] and int(lo[k]) + int(D[k]) <= lo_t[k] + self.dims[k] for k in range(3))
        if inside:
            sdf = sdf + 0.0  # as at_nodes adds a zero distance (-0.0 becomes 0.0)
        else:
            o = [g[k] - gc[k] for k in range(3)]
            off = torch.stack(
                torch.broadcast_tensors(o[0][:, None, None], o[1][None, :, None], o[2][None, None, :]), -1
            )
            sdf = sdf + off.reshape(-1, 3).to(torch.float32).norm(dim=1) * self.dx
        return sdf, self._unit_normals(dev)[flat]

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N,) signed distance (< 0 inside), trilinear in the node table."""
        _check_points(points)
        return self._plus_outside(self._lookup(self.node_sdf[..., None], points)[:, 0], points)

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N, 3) unit outward normal (interpolated sdf gradient)."""
        _check_points(points)
        return unit_or_up(self._lookup(self.node_normal, points))

    def sdf_normal(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """``(sdf(points), normal(points))`` from one trilinear lookup of both tables (the same values, bit for bit;
        the particle contact asks for both every step)."""
        _check_points(points)
        table = self.__dict__.get("_sdf_normal_table")
        if table is None:
            table = self._sdf_normal_table = torch.cat([self.node_sdf[..., None], self.node_normal], -1)  # (X,Y,Z,4)
        both = self._lookup(table, points)
        return self._plus_outside(both[:, 0], points), unit_or_up(both[:, 1:])

    def _plus_outside(self, d: Tensor, points: Tensor) -> Tensor:
        """Interpolated sdf ``d`` (N,) plus the distance of the (N, 3) points to the region box (0 inside it)."""
        return d + box_distance(points, self.lo.to(points), self.hi.to(points))


def box_distance(points: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    """(N,) Euclidean distance of (N, 3) points to the boxes ``[lo, hi]`` ((3,) or (N, 3) each; 0 inside)."""
    return (points - torch.clamp(points, lo, hi)).norm(dim=1)


def corner_sum(terms: Tensor) -> Tensor:
    """(N, C) sum of the (N, 8, C) trilinear corner terms (corner c = (cx, cy, cz), cx slowest) in a fixed pairwise
    order, three elementwise adds: every lookup that sums its corners here agrees bit for bit, whatever C."""
    h = terms[:, :4] + terms[:, 4:]
    h = h[:, :2] + h[:, 2:]
    return h[:, 0] + h[:, 1]


_UP: dict[tuple[torch.device, torch.dtype], Tensor] = {}


def unit_or_up(n: Tensor) -> Tensor:
    """(N, 3) vectors scaled to unit length; +z where a vector is (near) zero (or not finite)."""
    key = (n.device, n.dtype)
    up = _UP.get(key)
    if up is None:
        up = _UP.setdefault(key, torch.tensor([0.0, 0.0, 1.0], dtype=n.dtype, device=n.device))
    return unit_toward(n, up)


def unit_toward(n: Tensor, up: Tensor) -> Tensor:
    """(N, 3) vectors scaled to unit length; the (3,) ``up`` where a vector is (near) zero (or not finite):
    :func:`unit_or_up` with its +z given (a pure function, for compiled kernels)."""
    nn = n.norm(dim=1, keepdim=True)
    return torch.where(nn > 1e-12, n / torch.clamp(nn, min=1e-12), up)
