"""deform_mesh: seeded, smooth, watertight, volume-preserving, and actually deforming."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tvrecon.data.shapes import deform_mesh, make_shape


@pytest.mark.parametrize("name", ["cube", "torus", "fork", "mug", "gear", "bottle", "scissors", "star"])
def test_deform_keeps_watertight_and_volume(name: str) -> None:
    mesh = make_shape(name, 0)
    out = deform_mesh(mesh, seed=3, strength=0.15)
    assert out.is_watertight and out.is_winding_consistent
    assert out.body_count == 1
    assert abs(out.volume / mesh.volume - 1.0) < 0.02  # divergence-free flow: far inside the 20% requirement
    # it moved: mean distance of the new vertices to the old surface is a sizeable fraction of the strength
    dist = np.abs(trimesh.proximity.signed_distance(mesh, out.vertices[:: max(1, len(out.vertices) // 400)]))
    assert dist.mean() > 0.005, f"{name}: deformation too small ({dist.mean():.4f})"
    # ... but stays bounded by the strength (class recognizable): nothing moves more than ~strength * extent
    assert dist.max() < 0.15 * 1.5


def test_deform_deterministic_and_seeded() -> None:
    mesh = make_shape("cup", 2)
    a = deform_mesh(mesh, seed=11, strength=0.1)
    b = deform_mesh(mesh, seed=11, strength=0.1)
    c = deform_mesh(mesh, seed=12, strength=0.1)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    assert a.vertices.shape == c.vertices.shape
    assert np.abs(a.vertices - c.vertices).max() > 1e-3


def test_deform_is_smooth() -> None:
    """Neighbouring vertices move alike: relative displacement across an edge is tiny compared to the motion."""
    mesh = make_shape("ball", 0)  # no refinement needed: vertex i of the output is vertex i of the input
    out = deform_mesh(mesh, seed=5, strength=0.15)
    assert len(out.vertices) == len(mesh.vertices)
    disp = out.vertices - mesh.vertices
    edges = mesh.edges_unique
    rel = np.linalg.norm(disp[edges[:, 0]] - disp[edges[:, 1]], axis=1) / mesh.edges_unique_length
    assert np.linalg.norm(disp, axis=1).max() > 0.03
    assert rel.max() < 1.0  # Lipschitz < 1: a diffeomorphism, no fold-over


def test_strength_zero_is_identity_and_strength_scales() -> None:
    mesh = make_shape("egg", 0)
    np.testing.assert_array_equal(deform_mesh(mesh, 1, strength=0.0).vertices, mesh.vertices)
    small = np.abs(deform_mesh(mesh, 1, 0.02).vertices - mesh.vertices).max()
    large = np.abs(deform_mesh(mesh, 1, 0.2).vertices - mesh.vertices).max()
    assert large > 3 * small


def test_refines_large_faces() -> None:
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # 12 faces: would stay flat without refinement
    out = deform_mesh(box, seed=0, strength=0.1)
    assert len(out.faces) > 100 and out.is_watertight
    # the sides bend: a refined but undeformed box would still have only 6 distinct face normals
    assert len(np.unique(np.round(out.face_normals, 3), axis=0)) > 50


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seed": -1}, "non-negative int"),
        ({"seed": 0, "strength": 0.9}, r"strength must be in \[0, 0.5\]"),
        ({"seed": 0, "strength": float("nan")}, "strength"),
        ({"seed": 0, "modes": 0}, "modes and steps"),
    ],
)
def test_deform_bad_input(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        deform_mesh(make_shape("cube", 0), **kwargs)


def test_deform_rejects_empty() -> None:
    with pytest.raises(ValueError, match="non-empty trimesh"):
        deform_mesh(trimesh.Trimesh(), seed=0)
