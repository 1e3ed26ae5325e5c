"""Procedural shape classes: validity for several seeds, determinism, variety, thin-part thickness."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import trimesh

from tvrecon.data.shapes import CLASSES, RECON_CLASSES, available_classes, make_shape
from tvrecon.data.shapes.primitives import lathe, normalize, signed_volume, vessel

PAPER_RECON = {"bottle", "bowl", "can", "conditioner", "cube", "fork", "gear", "pepsi", "spoon", "scissors"}


@functools.cache
def _shape(name: str, seed: int) -> trimesh.Trimesh:
    return make_shape(name, seed)


def _assert_valid(mesh: trimesh.Trimesh, name: str) -> None:
    assert mesh.is_watertight, name
    assert mesh.is_winding_consistent, name
    assert mesh.body_count == 1, name
    assert mesh.volume > 1e-4, name
    assert np.all(np.isfinite(mesh.vertices)), name
    lo, hi = mesh.bounds
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6, err_msg=name)
    assert abs(float(np.max(hi - lo)) - 1.0) < 1e-6, name


def test_class_lists() -> None:
    assert len(CLASSES) == 35 and len(set(CLASSES)) == 35
    assert set(RECON_CLASSES) == PAPER_RECON
    assert CLASSES[:10] == RECON_CLASSES
    assert {"mug", "torus", "banana", "wrench", "hammer", "key", "cup", "plate"} <= set(CLASSES)
    assert available_classes() == CLASSES  # every class has a builder


@pytest.mark.parametrize("name", CLASSES)
@pytest.mark.parametrize("seed", [0, 1])
def test_every_class_valid(name: str, seed: int) -> None:
    _assert_valid(_shape(name, seed), name)


@pytest.mark.slow
@pytest.mark.parametrize("name", CLASSES)
def test_every_class_valid_many_seeds(name: str) -> None:
    for seed in (2, 3, 4, 17, 123):
        _assert_valid(make_shape(name, seed), f"{name} seed {seed}")


@pytest.mark.parametrize("name", CLASSES)
def test_seeds_differ(name: str) -> None:
    a, b = _shape(name, 0), _shape(name, 1)
    same = a.vertices.shape == b.vertices.shape and np.allclose(a.vertices, b.vertices)
    assert not same, f"{name}: seeds 0 and 1 gave the same mesh"


@pytest.mark.parametrize("name", RECON_CLASSES + ("torus", "mug", "key", "banana"))
def test_deterministic(name: str) -> None:
    again = make_shape(name, 1)
    ref = _shape(name, 1)
    np.testing.assert_array_equal(again.vertices, ref.vertices)
    np.testing.assert_array_equal(again.faces, ref.faces)


def _ray_thickness(mesh: trimesh.Trimesh, n: int = 1500) -> np.ndarray:
    """Local thickness at n surface samples: distance along the inward normal to where the ray leaves the solid."""
    pts, face = mesh.sample(n, return_index=True, seed=0)
    nrm = mesh.face_normals[face]
    hit, ray, _ = mesh.ray.intersects_location(pts - 1e-5 * nrm, -nrm, multiple_hits=False)
    d = np.full(n, np.inf)
    d[ray] = np.linalg.norm(hit - pts[ray], axis=1)
    return d


THIN = ("fork", "spoon", "scissors", "key", "knife", "wrench", "plate", "bowl", "cup", "mug", "wineglass", "pan")


@pytest.mark.parametrize("name", CLASSES)
def test_parts_thick_enough_for_voxels(name: str) -> None:
    """Thin parts (tines, blades, vessel walls) keep >= 2.5% of the extent (>= 3 cells at 128 voxels): 95% of the
    surface sees at least that much material behind it (the rest is wedge tips and rims where rays graze)."""
    for seed in (0, 1):
        d = _ray_thickness(_shape(name, seed))
        assert np.isfinite(d).mean() > 0.98, f"{name}: inward rays must hit the far side of a closed solid"
        floor = 0.025 if name in THIN else 0.02
        assert np.quantile(d, 0.05) >= floor, f"{name} seed {seed}: 5% thickness quantile {np.quantile(d, 0.05):.4f}"


@pytest.mark.parametrize(
    ("name", "euler"),
    [("torus", 0), ("mug", 0), ("nut", 0), ("key", 0), ("scissors", -2), ("padlock", 0), ("ball", 2), ("cup", 2)],
)
def test_topology(name: str, euler: int) -> None:
    """Through-holes are really open (Euler characteristic 2 - 2 * genus): rings, handles, bores, shackles."""
    for seed in (0, 1):
        assert _shape(name, seed).euler_number == euler, f"{name} seed {seed}"


def test_gear_has_a_bore() -> None:
    assert all(_shape("gear", seed).euler_number <= 0 for seed in (0, 1))


def test_make_shape_bad_input() -> None:
    with pytest.raises(ValueError, match="unknown shape class 'teapot'"):
        make_shape("teapot")
    with pytest.raises(ValueError, match="non-negative int"):
        make_shape("cube", -1)


def test_vessel_wall_thickness_and_cavity() -> None:
    phi = np.linspace(0.0, np.pi / 2, 30)
    shell, cavity = vessel(np.sin(phi), 1.0 - np.cos(phi), 0.1)
    assert shell.is_watertight and cavity.is_watertight
    # hemispherical shell of radius 1 with inner surface shifted by (-0.1, +0.1): volume between the two
    assert 0.3 < shell.volume < 2 * np.pi / 3 * (1 - 0.9**3) * 1.5
    # the wall is at least 0.1 thick: points 0.05 inside the outer surface (along the normal) are inside
    probe = np.array([[0.95 * np.sin(a), 0.0, 1.0 - 0.95 * np.cos(a)] for a in np.linspace(0.1, 1.4, 8)])
    assert shell.contains(probe).all()
    with pytest.raises(ValueError, match="non-decreasing"):
        vessel(np.array([0.0, 1.0, 0.5]), np.array([0.0, 0.5, 1.0]), 0.1)


def test_lathe_and_normalize() -> None:
    m = lathe(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [0.0, 2.0]]), sections=64)
    assert m.is_watertight and signed_volume(m) > 0
    np.testing.assert_allclose(m.volume, np.pi * 2.0, rtol=0.01)
    n = normalize(m)
    np.testing.assert_allclose(n.extents.max(), 1.0)
    with pytest.raises(ValueError, match=r"lathe profile must have shape \(n, 2\) with n >= 3"):
        lathe(np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"lathe profile must have shape \(n, 2\), got \(4, 3\)"):
        lathe(np.zeros((4, 3)))
