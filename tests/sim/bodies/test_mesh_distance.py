"""The capped node-to-surface distance of MeshCollider: the exact distance to the surface (against trimesh), never
farther than the plain sample query that it replaced, and right beside a vertex that many faces share."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from tvrecon.sim.bodies.mesh_distance import (
    distinct_samples,
    maybe_near,
    point_triangle_distance,
    surface_distance,
)
from tvrecon.sim.bodies.mesh_region import clip_to_box
from tvrecon.sim.bodies.voxelize import surface_samples


def _lattice(lo_i: np.ndarray, dims: np.ndarray, dx: float) -> np.ndarray:
    axes = [np.arange(lo_i[k], lo_i[k] + dims[k]) * dx for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def _plain(nodes: np.ndarray, surface: trimesh.Trimesh, dx: float, cap: float) -> np.ndarray:
    """The distance as MeshCollider computed it before 2026-11-27: every node queried, the faces of its 4 nearest
    samples measured, copies of one shared vertex included."""
    dist = np.full(len(nodes), cap)
    pts, fid = surface_samples(surface, spacing=dx / 2)
    sd, si = cKDTree(pts).query(nodes, k=4, distance_upper_bound=cap)
    close = np.flatnonzero(np.isfinite(sd[:, 0]))
    cand = fid[np.minimum(si[close], len(pts) - 1)]
    ok = np.isfinite(sd[close])
    tris = np.asarray(surface.triangles)[cand.reshape(-1)]
    q = np.repeat(nodes[close], 4, axis=0)
    exact = np.linalg.norm(trimesh.triangles.closest_point(tris, q) - q, axis=1).reshape(-1, 4)
    dist[close] = np.minimum(np.where(ok, exact, np.inf).min(1), cap)
    return dist


def test_maybe_near_keeps_every_node_with_a_point_within_the_cap():
    rng = np.random.default_rng(0)
    dx, cap = 1.0 / 64, 4.0 / 64
    lo_i, dims = np.array([20, 18, 30]), np.array([17, 15, 9])
    nodes = _lattice(lo_i, dims, dx)
    # points around the region, some just inside and some just outside the cap of a node
    pts = (lo_i + rng.uniform(-4, dims + 4, size=(40, 3))) * dx
    near = maybe_near(pts, lo_i, dims, dx, cap)
    d = cKDTree(pts).query(nodes, k=1)[0]
    assert near[d <= cap].all()
    assert not near.all()  # it does prune


def _exact(nodes: np.ndarray, surface: trimesh.Trimesh, cap: float) -> np.ndarray:
    """The true capped distance: trimesh's closest point over the whole surface."""
    return np.minimum(trimesh.proximity.closest_point(surface, nodes)[1], cap)


def test_surface_distance_is_the_exact_distance_and_never_farther_than_the_plain_query():
    dx, cap = 1.0 / 128, 4.0 / 128
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.08)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1.0, 2.0, 0.5]))
    mesh.apply_translation([0.5, 0.5, 0.45])
    lo_i, dims = np.array([50, 52, 48]), np.array([30, 25, 14])  # a slab cutting the sphere's top
    nodes = _lattice(lo_i, dims, dx)
    surface = clip_to_box(mesh, lo_i * dx - cap, (lo_i + dims - 1) * dx + cap)
    dist, n = surface_distance(nodes, lo_i, dims, surface, dx, cap)
    ref, exact = _plain(nodes, surface, dx, cap), _exact(nodes, surface, cap)
    assert n == len(surface_samples(surface, spacing=dx / 2)[0])
    assert np.abs(dist - exact).max() < 0.01 * dx  # 4 nearest points find the nearest face but rarely miss it
    assert (dist <= ref + 1e-12).all()
    assert (exact < cap).any() and (exact == cap).any()  # both kinds of node occur
    assert surface_distance(nodes, lo_i, dims, None, dx, cap)[0].tolist() == [cap] * len(nodes)


def test_a_node_beside_a_vertex_of_a_fan_of_thin_triangles_reads_its_true_distance():
    """A flat fan of 48 thin triangles round one vertex is ~96 copies of that vertex's sample (each face's lattice
    corner and longest-edge end). A node 0.08 cells above the fan and 0.12 cells beside its centre is nearer to the
    centre than to any other sample: the plain query found 4 copies, measured 4 of the 48 faces, none of which holds
    the node's foot, and read the node 1.8x too far (the centre's distance); the distinct points measure every face of
    the centre."""
    dx, cap = 1.0 / 128, 4.0 / 128
    lo_i, dims = np.array([60, 60, 60]), np.array([9, 9, 9])
    nodes = _lattice(lo_i, dims, dx)
    centre = np.array([64.12, 64.0, 63.92]) * dx  # node (64, 64, 64) is 0.08 cells above, 0.12 cells beside it
    k = 48
    ring = centre + 2.0 * dx * np.stack([np.cos(2 * np.pi * np.arange(k) / k), np.sin(2 * np.pi * np.arange(k) / k),
                                         np.zeros(k)], 1)  # fmt: skip
    fan = trimesh.Trimesh(
        vertices=np.vstack([centre, ring]), faces=[[0, 1 + i, 1 + (i + 1) % k] for i in range(k)], process=False
    )
    surface = clip_to_box(fan, lo_i * dx - cap, (lo_i + dims - 1) * dx + cap)
    pts, fid = surface_samples(surface, spacing=dx / 2)
    assert distinct_samples(pts, fid)[2].max() >= k  # the centre: one point, every face of the fan
    dist = surface_distance(nodes, lo_i, dims, surface, dx, cap)[0]
    ref, exact = _plain(nodes, surface, dx, cap), _exact(nodes, surface, cap)
    node = np.flatnonzero((np.abs(nodes / dx - [64, 64, 64]) < 0.5).all(1))[0]
    assert exact[node] == pytest.approx(0.08 * dx)
    assert dist[node] == pytest.approx(exact[node], abs=1e-9 * dx)
    assert ref[node] > 1.5 * exact[node]  # the control: the plain query reads this node too far
    assert np.abs(dist - exact).max() < 1e-3 * dx


def test_distinct_samples_merge_copies_and_keep_every_face():
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 0]])
    fid = np.array([0, 0, 1, 1, 2, 2])
    uniq, starts, counts, faces = distinct_samples(pts, fid)
    got = {tuple(p): sorted(faces[s : s + c].tolist()) for p, s, c in zip(uniq, starts, counts, strict=True)}
    assert got == {(0.0, 0.0, 0.0): [0, 1, 2], (0.0, 1.0, 0.0): [1], (1.0, 0.0, 0.0): [0, 2]}


def test_point_triangle_distance_matches_trimesh_in_every_region_and_on_degenerate_triangles():
    rng = np.random.default_rng(3)
    tris = rng.normal(size=(4000, 3, 3))
    tris[:50, 2] = tris[:50, 1]  # two vertices the same: a segment
    tris[50:100, 2] = 0.5 * (tris[50:100, 0] + tris[50:100, 1])  # collinear
    tris[100:120] = tris[100:120, :1]  # a point
    q = rng.normal(size=(4000, 3)) * 2.0
    ref = np.linalg.norm(trimesh.triangles.closest_point(tris, q) - q, axis=1)
    assert np.allclose(point_triangle_distance(tris, q), ref, rtol=1e-9, atol=1e-12)


def test_surface_distance_with_samples_but_no_node_within_the_cap():
    dx, cap = 1.0 / 128, 4.0 / 128
    lo_i, dims = np.array([10, 10, 10]), np.array([5, 5, 5])
    nodes = _lattice(lo_i, dims, dx)
    c = (lo_i - 3.8) * dx  # a small triangle in the corner of the grown box: 3.8 * sqrt(3) cells from the nearest node
    tri = trimesh.Trimesh(vertices=[c, c + [0.2 * dx, 0, 0], c + [0, 0.2 * dx, 0]], faces=[[0, 1, 2]])
    surface = clip_to_box(tri, lo_i * dx - cap, (lo_i + dims - 1) * dx + cap)
    dist, n = surface_distance(nodes, lo_i, dims, surface, dx, cap)
    assert n > 0 and not maybe_near(surface_samples(surface, dx / 2)[0], lo_i, dims, dx, cap).any()
    assert np.array_equal(dist, _plain(nodes, surface, dx, cap)) and (dist == cap).all()
