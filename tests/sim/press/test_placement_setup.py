"""The placement's shortcuts give what the plain computations give: the pad-inside count and the watertight flag."""

from __future__ import annotations

import torch
import trimesh

from tvrecon.sim.bodies.colliders import MeshCollider


def _sphere_collider() -> MeshCollider:
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    mesh.apply_translation([0.5, 0.5, 0.4])
    return MeshCollider(mesh, n_grid=64, region=([0.3, 0.3, 0.2], [0.7, 0.7, 0.6]))


def test_count_inside_equals_the_plain_count() -> None:
    """Boxes of points above, across and inside the sphere, and beyond the table: the same count as the sdf's."""
    col = _sphere_collider()
    g = torch.Generator().manual_seed(0)
    for lo, size in (
        ((0.4, 0.4, 0.58), 0.08),  # above the top (0.55): no negative node reachable
        ((0.42, 0.42, 0.5), 0.1),  # across the top
        ((0.45, 0.45, 0.35), 0.1),  # inside
        ((0.1, 0.1, 0.1), 0.9),  # the whole table and beyond it
        ((0.8, 0.8, 0.8), 0.1),  # outside the table
    ):
        pts = torch.tensor(lo) + size * torch.rand(500, 3, generator=g)
        assert col.count_inside(pts) == int((col.sdf(pts) < 0).sum())
    above = torch.tensor([0.4, 0.4, 0.58]) + 0.08 * torch.rand(500, 3, generator=g)
    col.sdf = None  # the shortcut decides without interpolating
    assert col.count_inside(above) == 0
    del col.sdf
    grid = torch.stack(torch.meshgrid(*[torch.linspace(0.3, 0.7, 30)] * 3, indexing="ij"), -1).reshape(-1, 3)
    assert col.count_inside(grid) == int((col.sdf(grid) < 0).sum()) > 0


def test_watertight_flag_gives_the_same_tables() -> None:
    """Passing the mesh's own ``is_watertight`` (the placement passes the caller's mesh's) changes nothing."""
    mesh = trimesh.creation.box(extents=(0.2, 0.3, 0.25))
    mesh.apply_translation([0.5, 0.5, 0.4])
    region = ([0.35, 0.3, 0.3], [0.65, 0.7, 0.6])
    plain = MeshCollider(mesh, n_grid=64, region=region)
    told = MeshCollider(mesh, n_grid=64, region=region, watertight=mesh.is_watertight)
    assert torch.equal(plain.node_sdf, told.node_sdf) and torch.equal(plain.node_normal, told.node_normal)
