"""The chart layout of the Chart-based method (Smith et al., NeurIPS 2020) and the graph that joins its charts.

The surface is a set of charts: small, separate triangle meshes whose vertices are not shared. The vision charts start
as a closed sphere-like layout: an icosahedron is subdivided ``base_subdivisions`` times (edge midpoints pushed onto
the unit sphere; 80 triangles for 1), each of its triangles becomes one chart, a triangular grid of
``chart_subdivisions`` segments per side pushed onto the sphere (21 vertices and 25 faces for 5), and the sphere is
scaled to the ellipsoid of :class:`~tvrecon.models.components.ellipsoid.EllipsoidTemplate` in front of the camera. The
authors start from 96 charts of 19 vertices and 24 faces read from a mesh file (``vision_sheets.obj``); 80 x 21 = 1,680
vertices is the same size, built here in code so that it can be resized.

Charts touch along their borders: the border vertices of neighbouring charts sit at the same position (*seam*
vertices) and, as in the authors' graph, every pair of vertices at one position is joined by an edge, so the charts
talk to each other while staying free to separate. A touch chart (a ``size x size`` grid, 5 x 5 as the authors') joins
the graph through its central vertex, which is linked to every seam vertex of the vision charts
(:func:`chart_adjacency`). The graph has self loops and is normalised by rows (the mean over a vertex's
neighbourhood).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import torch
from torch import Tensor, nn

from tvrecon.models.components.ellipsoid import mesh_edges, unpool_faces
from tvrecon.utils.shape_check import check_shape

__all__ = ["ChartTemplate", "chart_adjacency", "chart_sphere", "grid_chart_faces", "icosahedron"]


def icosahedron() -> tuple[Tensor, Tensor]:
    """The regular icosahedron on the unit sphere.

    Returns:
        verts (12, 3) float64 unit vectors and faces (20, 3) int64, counter-clockwise seen from outside.
    """
    p = (1.0 + math.sqrt(5.0)) / 2.0
    v = torch.tensor(
        [[-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0], [0, -1, p], [0, 1, p],
         [0, -1, -p], [0, 1, -p], [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1]],
        dtype=torch.float64,
    )  # fmt: skip
    f = torch.tensor(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]],
        dtype=torch.int64,
    )  # fmt: skip
    return v / v.norm(dim=1, keepdim=True), f


def grid_chart_faces(size: int) -> Tensor:
    """Faces of a ``size x size`` vertex grid (row-major vertex order), two triangles per cell.

    Returns:
        (2 (size - 1)^2, 3) int64, counter-clockwise when rows grow along +y and columns along +x.
    """
    if size < 2:
        raise ValueError(f"size must be >= 2 vertices per side, got {size}")
    r, c = torch.meshgrid(torch.arange(size - 1), torch.arange(size - 1), indexing="ij")
    a = (r * size + c).reshape(-1)
    b, d, e = a + 1, a + size, a + size + 1
    return torch.cat([torch.stack([a, b, e], 1), torch.stack([a, e, d], 1)]).long()


def _triangle_grid(n: int) -> tuple[Tensor, Tensor]:
    """Barycentric weights (V, 3) float64 of a triangle split into n segments per side and its faces (n^2, 3)."""
    index = {}
    weights = []
    for i in range(n + 1):
        for j in range(n + 1 - i):
            index[(i, j)] = len(weights)
            weights.append([(n - i - j) / n, i / n, j / n])
    faces = []
    for i in range(n):
        for j in range(n - i):
            faces.append([index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]])
            if i + j < n - 1:
                faces.append([index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]])
    return torch.tensor(weights, dtype=torch.float64), torch.tensor(faces, dtype=torch.int64)


def chart_sphere(base_subdivisions: int = 1, chart_subdivisions: int = 5) -> tuple[Tensor, Tensor, Tensor]:
    """Charts covering the unit sphere, one per triangle of a subdivided icosahedron.

    Args:
        base_subdivisions: edge-midpoint subdivisions of the icosahedron (20 * 4^s charts).
        chart_subdivisions: segments per side of each chart (its (n + 1)(n + 2) / 2 vertices, n^2 faces).

    Returns:
        verts (C * Vc, 3) float32 on the unit sphere (chart by chart), faces (C * Fc, 3) int64 (outward) and
        chart (C * Vc,) int64, the chart of every vertex.
    """
    if base_subdivisions < 0 or chart_subdivisions < 1:
        raise ValueError(
            f"need base_subdivisions >= 0 and chart_subdivisions >= 1, got {base_subdivisions} and {chart_subdivisions}"
        )
    verts, faces = icosahedron()
    for _ in range(base_subdivisions):
        faces, parent = unpool_faces(faces, verts.shape[0])
        mid = 0.5 * (verts[parent[:, 0]] + verts[parent[:, 1]])
        verts = torch.cat([verts, mid / mid.norm(dim=1, keepdim=True)])
    weights, chart_faces = _triangle_grid(chart_subdivisions)  # (Vc, 3), (Fc, 3)
    corners = verts[faces]  # (C, 3, 3)
    points = torch.einsum("vk,ckd->cvd", weights, corners)  # (C, Vc, 3)
    points = points / points.norm(dim=-1, keepdim=True)
    C, Vc = points.shape[:2]
    all_faces = (chart_faces[None] + Vc * torch.arange(C)[:, None, None]).reshape(-1, 3)
    chart = torch.arange(C).repeat_interleave(Vc)
    return points.reshape(-1, 3).float(), all_faces, chart


def _seam_pairs(verts: Tensor, chart: Tensor, decimals: int = 5) -> Tensor:
    """(S, 2) int64 pairs (i < j) of vertices of different charts at the same position."""
    key = torch.round(verts.double() * 10**decimals).long()
    _, group = torch.unique(key, dim=0, return_inverse=True)  # (V,)
    order = torch.argsort(group, stable=True)
    pairs = []
    g = group[order]
    start = 0
    for end in range(1, len(order) + 1):
        if end == len(order) or g[end] != g[start]:
            members = order[start:end]
            for a in range(len(members)):
                for b in range(a + 1, len(members)):
                    i, j = int(members[a]), int(members[b])
                    if chart[i] != chart[j]:
                        pairs.append((min(i, j), max(i, j)))
            start = end
    return torch.tensor(sorted(pairs), dtype=torch.int64).reshape(-1, 2)


class ChartTemplate(nn.Module):
    """The vision charts' initial layout in the camera frame, their seams and the touch chart grid, as buffers.

    Buffers: ``verts`` (Vv, 3) float32 (camera frame: the sphere scaled by ``radii`` at ``(0, 0, distance)``),
    ``faces`` (Fv, 3) int64, ``edges`` (Ev, 2) int64 (within charts), ``seams`` (S, 2) int64 (vertex pairs of different
    charts at one position), ``seam_verts`` (Vs,) int64 (the vertices on a seam), ``touch_faces`` (Ft, 3) int64 and
    ``touch_edges`` (Et, 2) int64 of one ``touch_size x touch_size`` touch chart.

    Args:
        base_subdivisions, chart_subdivisions: see :func:`chart_sphere`.
        radii: semi-axes (x, y, z) of the initial layout (those of the Pixel2Mesh ellipsoid by default).
        distance: its centre's depth along the camera's +z axis.
        touch_size: vertices per side of a touch chart (5 as the authors').
    """

    def __init__(
        self,
        base_subdivisions: int = 1,
        chart_subdivisions: int = 5,
        radii: Sequence[float] = (0.35, 0.35, 0.25),
        distance: float = 2.0,
        touch_size: int = 5,
    ) -> None:
        super().__init__()
        if len(radii) != 3 or min(radii) <= 0:
            raise ValueError(f"radii must be 3 positive numbers (x, y, z), got {list(radii)}")
        if touch_size < 3 or touch_size % 2 == 0:
            raise ValueError(f"touch_size must be odd and >= 3 (a touch chart has a central vertex), got {touch_size}")
        unit, faces, chart = chart_sphere(base_subdivisions, chart_subdivisions)
        seams = _seam_pairs(unit, chart)
        verts = unit * torch.tensor([float(r) for r in radii]) + torch.tensor([0.0, 0.0, float(distance)])
        self.touch_size = int(touch_size)
        self.num_charts = int(chart.max()) + 1
        self.register_buffer("verts", verts, persistent=False)
        self.register_buffer("faces", faces, persistent=False)
        self.register_buffer("edges", mesh_edges(faces), persistent=False)
        self.register_buffer("seams", seams, persistent=False)
        self.register_buffer("seam_verts", torch.unique(seams.flatten()), persistent=False)
        touch_faces = grid_chart_faces(self.touch_size)
        self.register_buffer("touch_faces", touch_faces, persistent=False)
        self.register_buffer("touch_edges", mesh_edges(touch_faces), persistent=False)

    @property
    def touch_verts(self) -> int:
        """Vertices of one touch chart."""
        return self.touch_size**2

    @property
    def touch_centre(self) -> int:
        """Index of a touch chart's central vertex within the chart."""
        return self.touch_verts // 2

    def faces_with_touches(self, touches: int) -> Tensor:
        """(Fv + T Ft, 3) int64: the vision charts' faces, then those of T touch charts (vertex Vv + t Vt + k)."""
        Vv, Vt = self.verts.shape[0], self.touch_verts
        offsets = Vv + Vt * torch.arange(touches, device=self.faces.device)
        touch = (self.touch_faces[None] + offsets[:, None, None]).reshape(-1, 3)
        return torch.cat([self.faces, touch])


def chart_adjacency(template: ChartTemplate, touch_used: Tensor | None, batch_size: int, seams: bool = True) -> Tensor:
    """Row-normalised graph of the vision charts and T touch charts, block-diagonal over a batch.

    Edges: self loops; the charts' own edges; every seam pair (with ``seams``); each touch chart's grid edges; and, for
    the touches in use, the touch chart's central vertex with every seam vertex (the authors' ``adj_fuse_touch``). A
    touch not in use keeps its chart's own edges only, so nothing reaches the vision charts from it.

    Args:
        template: the chart layout.
        touch_used: (B, T) bool, the touches whose chart joins the surface; None for no touch chart.
        batch_size: B.
        seams: join the vision charts along their seams. The authors' code adds the seam edges together with the touch
            charts, so their vision-only model has none: its charts meet only through the image.

    Returns:
        (B V, B V) float32 sparse CSR, V = Vv + T Vt; row v holds ``1 / |N(v)|`` at each neighbour (itself included).
    """
    device = template.verts.device
    Vv, Vt = template.verts.shape[0], template.touch_verts
    T = 0 if touch_used is None else touch_used.shape[1]
    if touch_used is not None:
        check_shape(touch_used, "(B, T)", "touch_used")
        if touch_used.shape[0] != batch_size:
            raise ValueError(f"touch_used must have shape ({batch_size}, T), got {tuple(touch_used.shape)}")
    V = Vv + T * Vt
    pairs = [template.edges, template.seams] if seams else [template.edges]
    if T:
        offsets = Vv + Vt * torch.arange(T, device=device)
        pairs.append((template.touch_edges[None] + offsets[:, None, None]).reshape(-1, 2))
    static = torch.cat(pairs)  # (E, 2) shared by every sample
    loops = torch.arange(V, device=device)
    rows = [torch.cat([static[:, 0], static[:, 1], loops])[None].expand(batch_size, -1)]
    cols = [torch.cat([static[:, 1], static[:, 0], loops])[None].expand(batch_size, -1)]
    batch_rows, batch_cols = [], []
    if T and touch_used is not None:
        seam = template.seam_verts  # (Vs,)
        centres = Vv + Vt * torch.arange(T, device=device) + template.touch_centre  # (T,)
        b, t = torch.nonzero(touch_used.to(device), as_tuple=True)  # used touches
        c = centres[t][:, None].expand(-1, seam.numel()).reshape(-1)  # (U Vs,)
        s = seam[None].expand(t.numel(), -1).reshape(-1)
        bb = b[:, None].expand(-1, seam.numel()).reshape(-1)
        batch_rows += [bb * V + c, bb * V + s]
        batch_cols += [bb * V + s, bb * V + c]
    offset = (torch.arange(batch_size, device=device) * V)[:, None]
    r = torch.cat([(rows[0] + offset).reshape(-1), *batch_rows])
    k = torch.cat([(cols[0] + offset).reshape(-1), *batch_cols])
    n = batch_size * V
    degree = torch.zeros(n, device=device).index_add_(0, r, torch.ones_like(r, dtype=torch.float32))
    values = 1.0 / degree[r]
    coo = torch.sparse_coo_tensor(torch.stack([r, k]), values, (n, n), check_invariants=False).coalesce()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return coo.to_sparse_csr()
