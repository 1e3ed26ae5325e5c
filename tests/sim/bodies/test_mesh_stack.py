"""``MeshStack``: B mesh colliders asked in one pass equal each collider asked alone, bit for bit; the batched contact
search (``near_surface`` with a stack) finds the same contacts as the loop over scenes."""

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.bodies.colliders import MeshCollider
from tvrecon.sim.bodies.mesh_stack import MeshStack
from tvrecon.sim.mpm.particle_contact import MeshStackCache, near_surface, scene_slices

DX = 1.0 / 64


def _colliders() -> list[MeshCollider]:
    """Three colliders of different shapes, poses and table sizes (one region smaller than the mesh)."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.12).apply_translation([0.5, 0.5, 0.3])
    box = trimesh.creation.box(extents=[0.2, 0.1, 0.15]).apply_translation([0.45, 0.55, 0.35])
    box.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0.3, 1.0, 0.2], point=[0.45, 0.55, 0.35]))
    torus = trimesh.creation.torus(0.1, 0.03).apply_translation([0.5, 0.48, 0.32])
    region = (np.array([0.38, 0.4, 0.25]), np.array([0.6, 0.62, 0.4]))
    return [
        MeshCollider(sphere, n_grid=64),
        MeshCollider(box, n_grid=64),
        MeshCollider(torus, n_grid=64, region=region),
    ]


def _points(n: int, seed: int) -> torch.Tensor:
    """Points around the bodies, some outside every table (the distance-to-region branch)."""
    g = torch.Generator().manual_seed(seed)
    return torch.tensor([0.3, 0.3, 0.15]) + 0.4 * torch.rand(n, 3, generator=g)


def test_stack_equals_each_collider_bit_for_bit():
    cols = _colliders()
    stack = MeshStack(cols, "cpu")
    x = _points(3000, 0)
    scene = torch.arange(3).repeat_interleave(1000)
    phi, n = stack.sdf_normal(x, scene)
    near = stack.near(x, scene, DX)
    assert torch.equal(stack.near(x, scene, DX, block=1000), near)  # the contiguous layout's broadcast path
    assert torch.equal(stack.near(x, scene, DX, block=999), near)  # not the layout: the per-point path
    for b, col in enumerate(cols):
        rows = scene == b
        phi_b, n_b = col.sdf_normal(x[rows])
        assert torch.equal(phi[rows], phi_b)
        assert torch.equal(n[rows], n_b)
        assert torch.equal(near[rows], col.near(x[rows], DX))
    assert (phi < DX).any() and (phi > DX).any()  # the points straddle the surfaces


def test_batched_search_finds_the_loops_contacts():
    cols = _colliders()
    x = _points(6000, 1)
    batch = torch.arange(3).repeat_interleave(2000)
    slices = scene_slices(batch, 3, 2000)
    idx, sc, phi, n = near_surface(x, cols, slices, DX)
    idx_s, sc_s, phi_s, n_s = near_surface(x, cols, slices, DX, batch, MeshStackCache())
    found = phi_s < DX  # the stacked search keeps the prefilter's other rows at +inf
    assert torch.isinf(phi_s[~found]).all()
    assert torch.equal(idx_s[found], idx) and torch.equal(sc_s[found], sc)
    assert torch.equal(phi_s[found], phi) and torch.equal(n_s[found], n)
    assert idx.numel() > 100
    blocked = near_surface(x, cols, slices, DX, batch, MeshStackCache(), block=2000)  # the press's layout
    assert all(torch.equal(a, b) for a, b in zip(blocked, (idx_s, sc_s, phi_s, n_s)))


def test_stack_cache_rebuilds_for_other_colliders():
    cols = _colliders()
    cache = MeshStackCache()
    a = cache.get(cols, torch.device("cpu"))
    assert cache.get(list(cols), torch.device("cpu")) is a  # same objects: kept
    assert cache.get(cols[:2], torch.device("cpu")) is not a  # a touch finished: rebuilt


def test_stack_rejects_mixed_cell_sizes():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1).apply_translation([0.5, 0.5, 0.3])
    with pytest.raises(ValueError, match="one cell size"):
        MeshStack([MeshCollider(sphere, n_grid=64), MeshCollider(sphere, n_grid=32)], "cpu")
