"""Initial ellipsoid mesh and edge-midpoint graph unpooling (Pixel2Mesh).

The ellipsoid is built procedurally as a UV sphere (``rings`` latitude rings of ``segments`` vertices plus two poles;
11 x 14 + 2 = 156 vertices by default, like Pixel2Mesh's), scaled by ``radii`` and placed in CAMERA coordinates at
``(0, 0, distance)`` (in front of an OpenCV camera looking along +z). Faces are oriented outward.

Unpooling adds one vertex at the midpoint of every edge and splits every triangle in 4, so a closed genus-0 mesh goes
from V to V + E = 4V - 6 vertices: 156 -> 618 -> 2466.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from tvrecon.utils.shape_check import check_shape

__all__ = ["EllipsoidTemplate", "mesh_edges", "unpool_faces", "unpool_features", "uv_ellipsoid"]


def uv_ellipsoid(
    radii: Sequence[float] = (0.35, 0.35, 0.25),
    distance: float = 2.0,
    rings: int = 11,
    segments: int = 14,
) -> tuple[Tensor, Tensor]:
    """Closed triangulated ellipsoid (UV sphere topology) in camera coordinates.

    Args:
        radii: semi-axes (x, y, z).
        distance: centre depth along the camera's +z axis.
        rings: latitude rings between the poles (>= 1).
        segments: vertices per ring (>= 3).

    Returns:
        verts (V, 3) float32 with V = rings * segments + 2, faces (F, 3) int64 with F = 2 * rings * segments,
        counter-clockwise seen from outside.
    """
    if rings < 1 or segments < 3:
        raise ValueError(f"need rings >= 1 and segments >= 3, got rings={rings}, segments={segments}")
    if len(radii) != 3 or min(radii) <= 0:
        raise ValueError(f"radii must be 3 positive numbers (x, y, z), got {radii}")
    theta = torch.arange(1, rings + 1, dtype=torch.float64) * torch.pi / (rings + 1)  # polar angle of each ring
    phi = torch.arange(segments, dtype=torch.float64) * 2 * torch.pi / segments
    th, ph = torch.meshgrid(theta, phi, indexing="ij")
    ring = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], dim=-1).reshape(-1, 3)
    unit = torch.cat([torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), ring, torch.tensor([[0.0, 0.0, -1.0]])])
    verts = unit * torch.tensor(radii, dtype=torch.float64) + torch.tensor([0.0, 0.0, distance], dtype=torch.float64)

    top, bottom = 0, rings * segments + 1
    s = torch.arange(segments)
    s1 = (s + 1) % segments
    faces = [torch.stack([torch.full_like(s, top), 1 + s, 1 + s1], dim=1)]
    for r in range(rings - 1):
        a, b = 1 + r * segments + s, 1 + r * segments + s1
        c, d = a + segments, b + segments
        faces += [torch.stack([a, c, d], dim=1), torch.stack([a, d, b], dim=1)]
    last = 1 + (rings - 1) * segments
    faces.append(torch.stack([last + s, torch.full_like(s, bottom), last + s1], dim=1))
    return verts.float(), torch.cat(faces).long()


def mesh_edges(faces: Tensor) -> Tensor:
    """Unique undirected edges of a triangle mesh.

    Args:
        faces: (F, 3) int64.

    Returns:
        (E, 2) int64, each row sorted (i < j), rows sorted lexicographically.
    """
    check_shape(faces, "(F, 3)", "faces")
    e = torch.cat([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = torch.sort(e, dim=1).values
    return torch.unique(e, dim=0)


def unpool_faces(faces: Tensor, num_verts: int) -> tuple[Tensor, Tensor]:
    """Edge-midpoint subdivision of the connectivity: one new vertex per edge, each triangle split in 4.

    Args:
        faces: (F, 3) int64 faces over ``num_verts`` vertices.
        num_verts: V.

    Returns:
        new_faces (4F, 3) int64 over V + E vertices (orientation kept) and parent_edges (E, 2) int64: new vertex
        ``V + e`` is the midpoint of ``parent_edges[e]``.
    """
    edges = mesh_edges(faces)  # (E, 2)
    key = edges[:, 0] * num_verts + edges[:, 1]
    order = torch.argsort(key)
    sorted_key = key[order]

    def mid(a: Tensor, b: Tensor) -> Tensor:
        k = torch.minimum(a, b) * num_verts + torch.maximum(a, b)
        return num_verts + order[torch.searchsorted(sorted_key, k)]

    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
    new_faces = torch.cat(
        [
            torch.stack([a, ab, ca], 1),
            torch.stack([ab, b, bc], 1),
            torch.stack([ca, bc, c], 1),
            torch.stack([ab, bc, ca], 1),
        ]
    )
    return new_faces, edges


def unpool_features(x: Tensor, parent_edges: Tensor) -> Tensor:
    """Append per-edge midpoints (mean of the two endpoints) to per-vertex features or coordinates.

    Args:
        x: (B, V, C) float.
        parent_edges: (E, 2) int64 from ``unpool_faces``.

    Returns:
        (B, V + E, C) float.
    """
    check_shape(x, "(B, V, C)", "x")
    return torch.cat([x, 0.5 * (x[:, parent_edges[:, 0]] + x[:, parent_edges[:, 1]])], dim=1)


class EllipsoidTemplate(nn.Module):
    """Initial ellipsoid and its unpooled levels, stored as buffers (they follow the module's device).

    Buffers per level ``s`` (0..levels-1): ``verts_s`` (V_s, 3) template vertices (the ellipsoid, unpooled),
    ``faces_s`` (F_s, 3), ``edges_s`` (E_s, 2); for s >= 1 ``parent_s`` (E_{s-1}, 2), the edges of level s-1 whose
    midpoints are level s's new vertices.

    Args:
        levels: number of mesh resolutions (3 for Pixel2Mesh: 156 -> 618 -> 2466).
        radii, distance, rings, segments: see ``uv_ellipsoid``.
    """

    def __init__(
        self,
        levels: int = 3,
        radii: Sequence[float] = (0.35, 0.35, 0.25),
        distance: float = 2.0,
        rings: int = 11,
        segments: int = 14,
    ) -> None:
        super().__init__()
        if levels < 1:
            raise ValueError(f"levels must be >= 1, got {levels}")
        self.levels = levels
        verts, faces = uv_ellipsoid(radii, distance, rings, segments)
        for s in range(levels):
            if s > 0:
                faces, parent = unpool_faces(faces, verts.shape[0])
                verts = unpool_features(verts[None], parent)[0]
                self.register_buffer(f"parent_{s}", parent, persistent=False)
            self.register_buffer(f"verts_{s}", verts, persistent=False)
            self.register_buffer(f"faces_{s}", faces, persistent=False)
            self.register_buffer(f"edges_{s}", mesh_edges(faces), persistent=False)

    def verts(self, level: int) -> Tensor:
        """(V_level, 3) float template vertices."""
        return getattr(self, f"verts_{level}")

    def faces(self, level: int) -> Tensor:
        """(F_level, 3) int64."""
        return getattr(self, f"faces_{level}")

    def edges(self, level: int) -> Tensor:
        """(E_level, 2) int64."""
        return getattr(self, f"edges_{level}")

    def parent_edges(self, level: int) -> Tensor:
        """(E_{level-1}, 2) int64 edges of the coarser level, for level >= 1."""
        if level < 1:
            raise ValueError("level 0 has no parent edges")
        return getattr(self, f"parent_{level}")
