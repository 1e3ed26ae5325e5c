"""The capped node-to-surface distance of MeshCollider: its shortcuts leave every value as the plain query had it."""

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from tvrecon.sim.bodies.mesh_distance import maybe_near, surface_distance
from tvrecon.sim.bodies.mesh_region import clip_to_box
from tvrecon.sim.bodies.voxelize import surface_samples


def _lattice(lo_i: np.ndarray, dims: np.ndarray, dx: float) -> np.ndarray:
    axes = [np.arange(lo_i[k], lo_i[k] + dims[k]) * dx for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def _plain(nodes: np.ndarray, surface: trimesh.Trimesh, dx: float, cap: float) -> np.ndarray:
    """The distance as MeshCollider computed it before the shortcuts: every node queried, every candidate measured."""
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


def test_surface_distance_equals_the_plain_query_bit_for_bit():
    dx, cap = 1.0 / 128, 4.0 / 128
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.08)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1.0, 2.0, 0.5]))
    mesh.apply_translation([0.5, 0.5, 0.45])
    lo_i, dims = np.array([50, 52, 48]), np.array([30, 25, 14])  # a slab cutting the sphere's top
    nodes = _lattice(lo_i, dims, dx)
    surface = clip_to_box(mesh, lo_i * dx - cap, (lo_i + dims - 1) * dx + cap)
    dist, n = surface_distance(nodes, lo_i, dims, surface, dx, cap)
    ref = _plain(nodes, surface, dx, cap)
    assert n == len(surface_samples(surface, spacing=dx / 2)[0])
    assert np.array_equal(dist, ref)
    assert (ref < cap).any() and (ref == cap).any()  # both kinds of node occur
    assert surface_distance(nodes, lo_i, dims, None, dx, cap)[0].tolist() == [cap] * len(nodes)


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
