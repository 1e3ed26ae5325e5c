"""Voxel carving of closed and open meshes, occupancy SDF, particle export."""

import os

import numpy as np
import pytest
import trimesh

from tvrecon.sim.bodies.voxelize import occupancy_sdf, save_particles_ply, surface_samples, voxelize


def test_closed_box_is_solid():
    box = trimesh.creation.box((1.0, 0.6, 0.4))
    vg = voxelize(box, pitch=0.1)
    assert vg.occupancy.sum() == 10 * 6 * 4
    c = vg.centers()
    assert np.allclose(c.min(0), [-0.45, -0.25, -0.15]) and np.allclose(c.max(0), [0.45, 0.25, 0.15])


def test_sphere_volume():
    s = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    vg = voxelize(s, pitch=0.05)
    vol = vg.occupancy.sum() * 0.05**3
    assert vol == pytest.approx(s.volume, rel=0.08)


def test_open_box_keeps_walls_and_bottom():
    """A box with its top face removed voxelizes like a cup: walls and bottom solid, interior carved."""
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    open_box = trimesh.Trimesh(box.vertices, box.faces[box.face_normals[:, 2] < 0.5], process=False)
    assert not open_box.is_watertight
    vg = voxelize(open_box, pitch=0.1)
    occ = vg.occupancy
    assert occ.shape == (12, 12, 12)
    z_bottom = np.argmin(np.abs(vg.origin[2] + np.arange(12) * 0.1 + 0.5))  # voxel layer on the bottom face
    assert occ[3:9, 3:9, z_bottom].all()  # bottom
    assert occ[np.argmin(np.abs(vg.origin[0] + np.arange(12) * 0.1 + 0.5)), 3:9, 3:9].all()  # the -x wall
    assert not occ[3:9, 3:9, 4:9].any()  # interior visible through the opening: carved
    assert not occ[:, :, -1].any()  # nothing above the box


def test_surface_samples_spacing():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    pts, fid = surface_samples(box, spacing=0.1)
    assert pts.shape[1] == 3 and len(fid) == len(pts)
    assert np.allclose(np.abs(pts).max(1), 0.5)  # all on the surface
    q = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 2))
    top = np.c_[q, np.full(200, 0.5)]
    d = np.linalg.norm(top[:, None] - pts[None], axis=2).min(1)
    assert d.max() < 0.1


def test_occupancy_sdf_signs():
    occ = np.zeros((9, 9, 9), bool)
    occ[2:7, 2:7, 2:7] = True
    sdf = occupancy_sdf(occ, pitch=0.5)
    assert sdf[4, 4, 4] == pytest.approx(-(3 * 0.5 - 0.25))
    assert sdf[2, 4, 4] == pytest.approx(-0.25) and sdf[1, 4, 4] == pytest.approx(0.25)
    assert sdf[0, 4, 4] == pytest.approx(0.75)
    with pytest.raises(ValueError, match=r"occupancy must have shape \(X, Y, Z\), got \(9, 9\)"):
        occupancy_sdf(occ[0], 0.5)


def test_save_particles_ply(tmp_path):
    x = np.random.default_rng(0).random((50, 3))
    path = save_particles_ply(tmp_path / "sub" / "p.ply", x)
    loaded = trimesh.load(path)
    assert np.allclose(np.asarray(loaded.vertices), x)
    assert [p.name for p in path.parent.iterdir()] == ["p.ply"]  # no temp files left behind
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # the usual mode, not mkstemp's 0600
    with pytest.raises(ValueError, match=r"x must have shape \(P, 3\), got \(\d+, 2\)"):
        save_particles_ply(tmp_path / "q.ply", x[:, :2])


def test_bad_mesh():
    with pytest.raises(ValueError, match="empty"):
        voxelize(trimesh.Trimesh(), pitch=0.1)
    with pytest.raises(ValueError, match="pitch"):
        voxelize(trimesh.creation.box(), pitch=0.0)
