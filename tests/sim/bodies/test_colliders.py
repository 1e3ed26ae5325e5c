"""Collider signed distances and normals: analytic shapes and the mesh table against the analytic sphere."""

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.bodies.colliders import Collider, MeshCollider, PlaneCollider, SphereCollider

DX = 1.0 / 128
REGION = (
    np.array([0.5 - 12 * DX, 0.5 - 12 * DX, 0.4 - 6 * DX]),
    np.array([0.5 + 12 * DX, 0.5 + 12 * DX, 0.4 + 6 * DX]),
)


def test_sphere_sdf_and_normal():
    col = SphereCollider((0.5, 0.5, 0.3), 0.1)
    p = torch.tensor([[0.5, 0.5, 0.3], [0.5, 0.5, 0.45], [0.5, 0.55, 0.3], [0.65, 0.5, 0.3]])
    assert torch.allclose(col.sdf(p), torch.tensor([-0.1, 0.05, -0.05, 0.05]), atol=1e-6)
    n = col.normal(p)
    assert torch.allclose(n[1:], torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    assert torch.allclose(n.norm(dim=1), torch.ones(4))
    assert isinstance(col, Collider)


def test_plane_sdf_and_normal():
    col = PlaneCollider((0.0, 0.0, 0.2), (0.0, 0.0, 2.0))
    p = torch.tensor([[0.3, 0.1, 0.1], [0.9, 0.9, 0.25]])
    assert torch.allclose(col.sdf(p), torch.tensor([-0.1, 0.05]), atol=1e-6)
    assert torch.allclose(col.normal(p), torch.tensor([[0.0, 0.0, 1.0]] * 2))


def _sphere_mesh():
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    m.apply_translation([0.5, 0.5, 0.3])
    return m


def _near_surface_points(n=4000):
    g = torch.Generator().manual_seed(0)
    lo, hi = (torch.as_tensor(r, dtype=torch.float32) for r in REGION)
    return lo + (hi - lo) * torch.rand(n, 3, generator=g)


def test_mesh_collider_matches_analytic_sphere():
    mc = MeshCollider(_sphere_mesh(), n_grid=128, region=REGION)
    ref = SphereCollider((0.5, 0.5, 0.3), 0.1)
    p = _near_surface_points()
    d = ref.sdf(p)
    near = d.abs() < 3 * DX  # the table clamps |sdf| at 4 cells (only the sign matters farther away)
    assert near.sum() > 500
    assert (mc.sdf(p) - d)[near].abs().max() < 0.2 * DX  # polygonal sphere + sampled distance
    assert ((mc.sdf(p) < 0) != (d < 0))[d.abs() > 0.2 * DX].sum() == 0
    assert (mc.normal(p) - ref.normal(p))[near].norm(dim=1).max() < 0.15
    assert mc.sdf(p).dtype == torch.float32


def test_mesh_collider_open_mesh_has_solid_shell():
    """A sphere with its bottom cap removed (not watertight) still blocks a pad arriving from above."""
    m = _sphere_mesh()
    open_mesh = trimesh.Trimesh(m.vertices, m.faces[m.face_normals[:, 2] > -0.3], process=False)
    assert not open_mesh.is_watertight
    mc = MeshCollider(open_mesh, n_grid=128, region=REGION)
    top = torch.tensor([[0.5, 0.5, 0.4 - 0.3 * DX], [0.5, 0.5, 0.4 + 2 * DX], [0.52, 0.5, 0.4 - 0.2 * DX]])
    sdf = mc.sdf(top)
    assert sdf[0] < 0 and sdf[2] < 0  # just under the cap: solid
    assert sdf[1] > 0  # above: free
    assert mc.normal(top)[1, 2] > 0.9  # outward normal points up


def test_mesh_collider_outside_region_is_outside():
    mc = MeshCollider(_sphere_mesh(), n_grid=128, region=REGION)
    far = torch.tensor([[0.9, 0.9, 0.9]])
    assert mc.sdf(far)[0] > 0.3


def test_bad_inputs():
    with pytest.raises(ValueError, match="radius"):
        SphereCollider((0.5, 0.5, 0.5), 0.0)
    with pytest.raises(ValueError, match="non-zero"):
        PlaneCollider((0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\), got \(3,\)"):
        SphereCollider((0.5, 0.5, 0.5), 0.1).sdf(torch.zeros(3))
    with pytest.raises(ValueError, match="empty"):
        MeshCollider(trimesh.Trimesh(), n_grid=32)
    bad = _sphere_mesh()
    bad.vertices[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        MeshCollider(bad, n_grid=32)


def test_mesh_collider_long_faces_cost_follows_region():
    """A 64-section cylinder has side faces 100 cells long: only their part near the region is sampled."""
    m = trimesh.creation.cylinder(radius=0.3, height=0.8, sections=64)
    m.apply_translation([0.5 - 0.3 + 8 * DX, 0.5, 0.5])  # side surface crosses the region at x ~ 0.5 + 8 dx
    lo = np.array([0.5 - 4 * DX, 0.5 - 12 * DX, 0.5 - 12 * DX])
    hi = np.array([0.5 + 14 * DX, 0.5 + 12 * DX, 0.5 + 12 * DX])
    mc = MeshCollider(m, n_grid=128, region=(lo, hi))
    # the surface inside the grown region is ~ 32 x 32 cells at 16 samples per cell^2 (x2 for the lattice):
    # whole near faces (the old sampling) would give > 1 M samples
    assert 0 < mc.n_samples < 60_000
    dims = mc.dims
    axes = [(mc.lo_index[k].item() + np.arange(dims[k])) * DX for k in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    ref = -trimesh.proximity.signed_distance(m, nodes)  # trimesh: > 0 inside
    near = np.abs(ref) < 2 * DX
    assert near.sum() > 1000
    err = np.abs(mc.node_sdf.numpy().reshape(-1) - ref)[near]
    assert err.max() < 0.05 * DX


def test_mesh_collider_at_nodes_equals_lookup():
    """The MPM grid's gather at lattice nodes equals the trilinear sdf / normal there (inside and outside the table)."""
    mc = MeshCollider(_sphere_mesh(), n_grid=128, region=REGION)
    lo = np.floor(REGION[0] / DX).astype(int) - 3
    hi = np.ceil(REGION[1] / DX).astype(int) + 3
    g = torch.Generator().manual_seed(1)
    idx = torch.stack([torch.randint(int(lo[k]), int(hi[k]) + 1, (3000,), generator=g) for k in range(3)], 1)
    sdf, n = mc.at_nodes(idx)
    pos = idx.to(torch.float32) * DX
    assert torch.allclose(sdf, mc.sdf(pos), atol=1e-6)
    assert torch.allclose(n, mc.normal(pos), atol=1e-5)


def test_mesh_collider_at_block_equals_at_nodes_bitwise():
    """The solver's per-block gather gives at_nodes' values bit for bit, inside the table and across its edges."""
    mc = MeshCollider(_sphere_mesh(), n_grid=128, region=REGION)
    lo_t = [int(v) for v in mc.lo_index.long().tolist()]
    blocks = [(lo_t, list(mc.dims)), ([lo_t[0] + 3, lo_t[1] + 2, lo_t[2] + 1], [7, 5, 4])]
    blocks.append(([lo_t[0] - 4, lo_t[1] + 5, lo_t[2] - 2], [mc.dims[0] + 8, 6, mc.dims[2] + 5]))  # leaves the table
    for lo, D in blocks:
        axes = [torch.arange(D[k]) + lo[k] for k in range(3)]
        idx = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        sdf, n = mc.at_nodes(idx)
        sdf_b, n_b = mc.at_block(lo, D)
        assert torch.equal(sdf_b, sdf) and torch.equal(n_b, n)


def test_mesh_collider_near_is_a_superset_of_the_points_within_reach_and_sdf_normal_is_both():
    """The particle contact's prefilter keeps every point with sdf < reach (inside, at cell faces and nodes, outside
    the table) and drops most far ones; ``sdf_normal`` is ``sdf`` and ``normal`` bit for bit."""
    mc = MeshCollider(_sphere_mesh(), n_grid=128, region=REGION)
    g = torch.Generator().manual_seed(3)
    lo, hi = torch.tensor(REGION[0]) - 4 * DX, torch.tensor(REGION[1]) + 4 * DX
    pts = lo + (hi - lo) * torch.rand(20_000, 3, generator=g)
    on_nodes = torch.round(pts[:2000] / DX) * DX  # exactly on lattice nodes (cell faces in every axis)
    pts = torch.cat([pts, on_nodes]).to(torch.float32)
    sdf = mc.sdf(pts)
    for reach in (0.25 * DX, DX, 2 * DX):
        near = mc.near(pts, reach)
        within = sdf < reach
        assert within.sum() > 100 and bool(near[within].all())
        assert near.sum() < 0.5 * len(pts) and near.sum() <= (sdf < reach + 2.5 * DX).sum()
    s2, n2 = mc.sdf_normal(pts)
    assert torch.equal(s2, sdf) and torch.equal(n2, mc.normal(pts))


def test_open_plane_from_above_is_solid_below_and_a_shell_otherwise():
    """A zero-thickness plane between node planes had no solid node (the pad went through it)."""
    z0 = 0.5 + 0.5 / 32  # half-way between the node planes, where the press puts the touch plane
    plane = trimesh.Trimesh([[0.3, 0.3, z0], [0.7, 0.3, z0], [0.7, 0.7, z0], [0.3, 0.7, z0]], [[0, 1, 2], [0, 2, 3]])
    region = ([0.4, 0.4, 0.4], [0.6, 0.6, 0.6])
    pts = torch.tensor([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5 - 3 / 32], [0.5, 0.5, 0.5 + 1 / 32]], dtype=torch.float64)
    above = MeshCollider(plane, n_grid=32, region=region, from_above=True)
    assert above.offset == 0.0
    sdf = above.sdf(pts)
    assert sdf[0] < 0 and sdf[1] < 0 and sdf[2] > 0  # behind the surface the pad meets: solid, in front: free
    assert float(sdf[0]) == pytest.approx(-0.5 / 32, abs=1e-6)  # like a closed box's top face
    assert float(above.normal(pts)[1, 2]) > 0.99
    shell = MeshCollider(plane, n_grid=32, region=region)  # no approach side: a 2-cell shell
    assert shell.offset == pytest.approx(1 / 32)
    sdf = shell.sdf(pts)
    assert sdf[0] < 0 and sdf[2] < 0 and sdf[1] > 0


def test_mesh_collider_signs_its_nodes_in_the_source_frame_as_in_its_own():
    """``sign_frame``: the inside test of a watertight mesh cast on the same object in another frame (turned, moved
    and scaled, as the press keeps the object's own mesh) gives the table of the domain-frame test, and a source mesh
    that is not the same object gives another table (the frame is used, not ignored)."""
    world = trimesh.creation.box(extents=(0.8, 0.5, 0.3))  # the object in its own frame (world units)
    R = trimesh.transformations.rotation_matrix(0.7, [0.3, 1.0, 0.2])[:3, :3]
    origin, scale = np.array([0.2, -0.4, 1.0]), 2.5
    # the domain-frame mesh: world = origin + scale R dom, so dom = R^T (world - origin) / scale
    dom = trimesh.Trimesh((np.asarray(world.vertices) - origin) @ R / scale, world.faces, process=False)
    lo, hi = dom.bounds[0] - 2 * DX, dom.bounds[1] + 2 * DX
    kw = {"n_grid": 128, "region": (lo, hi), "watertight": True}
    ref = MeshCollider(dom, **kw)
    new = MeshCollider(dom, **kw, sign_frame=(world, R, origin, scale))
    assert int((ref.node_sdf < 0).sum()) > 100 and int((ref.node_sdf > 0).sum()) > 100
    assert torch.equal(new.node_sdf, ref.node_sdf) and torch.equal(new.node_normal, ref.node_normal)
    moved = MeshCollider(dom, **kw, sign_frame=(world, R, origin + 0.1, scale))
    assert not torch.equal(moved.node_sdf < 0, ref.node_sdf < 0)
    with pytest.raises(ValueError, match="rotation"):
        MeshCollider(dom, **kw, sign_frame=(world, R[:2], origin, scale))
