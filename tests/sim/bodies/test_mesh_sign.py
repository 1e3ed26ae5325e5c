"""``mesh_sign.contains`` answers what ``mesh.contains`` answers, point for point."""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from tvrecon.data.shapes.registry import available_classes, make_shape
from tvrecon.sim.bodies.mesh_sign import contains


def _lattice(mesh: trimesh.Trimesh, n: int = 24) -> np.ndarray:
    """(n^3, 3) nodes over the mesh's bounding box grown by 10%."""
    lo, hi = mesh.bounds
    pad = 0.1 * (hi - lo)
    axes = [np.linspace(lo[k] - pad[k], hi[k] + pad[k], n) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def _fresh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices=np.array(mesh.vertices), faces=np.array(mesh.faces), process=False)


def test_contains_equals_trimesh_on_data_shapes() -> None:
    """Every third data-set shape, turned at random: the same booleans (inside, outside, outside the box)."""
    rng = np.random.default_rng(0)
    for name in available_classes()[::3]:
        mesh = make_shape(name, 0)
        mesh = trimesh.Trimesh(vertices=Rotation.random(random_state=rng).apply(mesh.vertices), faces=mesh.faces)
        if not mesh.is_watertight:
            continue
        pts = _lattice(mesh)
        want = _fresh(mesh).contains(pts)
        assert 0 < want.sum() < len(pts)
        np.testing.assert_array_equal(contains(_fresh(mesh), pts), want, err_msg=name)


def test_contains_with_a_cavity_and_outside_the_box() -> None:
    """A box with a closed cavity (4 walls on a ray) and points beyond the bounding box."""
    outer = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    inner = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    inner.invert()
    shell = trimesh.util.concatenate([outer, inner])
    pts = _lattice(shell, 20) * 1.3
    want = _fresh(shell).contains(pts)
    np.testing.assert_array_equal(contains(_fresh(shell), pts), want)
    assert want.any() and not contains(shell, np.array([[0.0, 0.0, 0.0], [5.0, 5.0, 5.0]])).any()
