"""Views: camera conventions, projection consistency of the ray-cast renderer, determinism, input checks."""

import time

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.data.views import Camera, _look_at_rotation, project_points, render_view, sample_camera
from tvrecon.utils.geometry import world_to_camera


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=0.4)


@pytest.fixture(scope="module")
def torus() -> trimesh.Trimesh:
    return trimesh.creation.torus(major_radius=0.3, minor_radius=0.12)


def test_sample_camera_conventions() -> None:
    for seed in range(5):
        cam = sample_camera(seed, image_size=64, distance=2.5, fov_deg=40.0)
        R = cam.RT[:, :3].double()
        assert cam.K.dtype == torch.float32 and cam.RT.dtype == torch.float32
        assert torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-5)
        assert torch.det(R) == pytest.approx(1.0, abs=1e-5)
        assert cam.center.norm().item() == pytest.approx(2.5, rel=1e-5)
        # the origin is straight ahead (+z) and lands on the image centre (pixel centres at integers)
        origin_cam = world_to_camera(torch.zeros(1, 3), cam.RT)[0]
        assert origin_cam[2].item() == pytest.approx(2.5, rel=1e-5)
        uv = project_points(torch.zeros(1, 3), cam.K, cam.RT)[0]
        assert torch.allclose(uv, torch.tensor([31.5, 31.5]), atol=1e-4)
        # fov: a point at the half-angle sits on the image border (u = -0.5 is the left edge)
        f = cam.K[0, 0].item()
        assert 32.0 / f == pytest.approx(np.tan(np.deg2rad(20.0)), rel=1e-5)
    assert not torch.equal(sample_camera(0).RT, sample_camera(1).RT)
    assert torch.equal(sample_camera(7).RT, sample_camera(7).RT)


def test_look_at_handles_vertical_views() -> None:
    for forward in ([0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1e-9, 0.0, -1.0]):
        R = _look_at_rotation(np.array(forward), np.array([0.0, 0.0, 1.0]))
        assert np.isfinite(R).all()
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9)
        assert np.allclose(R[2], np.array(forward) / np.linalg.norm(forward))


def test_image_up_is_world_up() -> None:
    """A point above the origin (world +z) appears above the image centre (smaller v): y points down."""
    cam = sample_camera(3)
    uv = project_points(torch.tensor([[0.0, 0.0, 0.3]]), cam.K, cam.RT)[0]
    assert uv[1] < (cam.height - 1) / 2


def test_project_points_matches_pinhole_formula() -> None:
    cam = sample_camera(11, image_size=100)
    pts = torch.rand(20, 3) - 0.5
    cam_pts = pts.double() @ cam.RT[:, :3].double().T + cam.RT[:, 3].double()
    hom = cam_pts @ cam.K.double().T
    expected = hom[:, :2] / hom[:, 2:]
    assert torch.allclose(project_points(pts, cam.K, cam.RT).double(), expected, atol=1e-3)


def test_hit_point_projects_onto_its_pixel(torus: trimesh.Trimesh) -> None:
    """Shoot an independent ray through a rendered pixel's centre: its hit projects back onto that pixel and the
    rendered depth is the hit's camera-frame z."""
    cam = sample_camera(5, image_size=96)
    out = render_view(torus, cam, seed=0)
    vs, us = torch.nonzero(out["mask"], as_tuple=True)
    assert len(us) > 200
    pick = torch.randperm(len(us), generator=torch.Generator().manual_seed(0))[:25]
    K = cam.K.double().numpy()
    R, t = cam.RT[:, :3].double().numpy(), cam.RT[:, 3].double().numpy()
    center = -R.T @ t
    for i in pick.tolist():
        u, v = int(us[i]), int(vs[i])
        d = R.T @ (np.linalg.inv(K) @ np.array([u, v, 1.0]))
        d /= np.linalg.norm(d)
        locs, _, _ = trimesh.ray.ray_triangle.RayMeshIntersector(torus).intersects_location(
            center[None], d[None], multiple_hits=True
        )
        assert len(locs) > 0
        hit = locs[np.argmin(np.linalg.norm(locs - center, axis=1))]
        uv = project_points(torch.tensor(hit[None], dtype=torch.float64), cam.K, cam.RT)[0]
        assert abs(uv[0].item() - u) < 1e-3 and abs(uv[1].item() - v) < 1e-3
        assert out["depth"][v, u].item() == pytest.approx(R[2] @ hit + t[2], abs=1e-4)


def test_sphere_silhouette_and_depth(sphere: trimesh.Trimesh) -> None:
    """Analytic check: the mask is the set of pixel rays passing within the sphere radius, the depth of the centre
    pixel is distance - radius."""
    size, dist, r = 81, 2.0, 0.4
    cam = sample_camera(2, image_size=size, distance=dist)
    out = render_view(sphere, cam, seed=3)
    origins, dirs = cam.pixel_rays()
    closest = np.linalg.norm(origins - (origins * dirs).sum(1, keepdims=True) * dirs, axis=1).reshape(size, size)
    analytic = closest < r
    ring = np.abs(closest - r) < 0.01  # the tessellated sphere may differ from the true one only near its rim
    mask = out["mask"].numpy()
    assert (mask == analytic)[~ring].all()
    assert out["depth"][40, 40].item() == pytest.approx(dist - r, abs=2e-3)


def test_mask_depth_image_agree(torus: trimesh.Trimesh) -> None:
    cam = sample_camera(1, image_size=64)
    out = render_view(torus, cam, seed=4, background=0.9)
    img, depth, mask = out["image"], out["depth"], out["mask"]
    assert img.shape == (3, 64, 64) and img.dtype == torch.float32
    assert depth.shape == (64, 64) and depth.dtype == torch.float32
    assert mask.shape == (64, 64) and mask.dtype == torch.bool
    assert torch.equal(mask, depth > 0)
    assert img.min() >= 0 and img.max() <= 1
    assert torch.all(img[:, ~mask] == 0.9)
    d = depth[mask]  # the torus lies within 0.42 of the origin, the camera at 2.0
    assert d.min() > 2.0 - 0.43 and d.max() < 2.0 + 0.43
    assert img[:, mask].std(dim=1).max() > 0.01  # actually shaded, not flat


def test_render_determinism(torus: trimesh.Trimesh) -> None:
    cam = sample_camera(0, image_size=48)
    a, b = render_view(torus, cam, seed=9), render_view(torus, cam, seed=9)
    c = render_view(torus, cam, seed=10)
    for k in ("image", "depth", "mask"):
        assert torch.equal(a[k], b[k])
    assert torch.equal(a["mask"], c["mask"]) and not torch.equal(a["image"], c["image"])


def test_render_speed_224(torus: trimesh.Trimesh) -> None:
    cam = sample_camera(0)
    render_view(torus, cam)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        render_view(torus, cam)
        times.append(time.perf_counter() - t0)
    assert sorted(times)[1] < 0.5


def test_bad_inputs(torus: trimesh.Trimesh) -> None:
    cam = sample_camera(0, image_size=16)
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        project_points(torch.zeros(4, 2), cam.K, cam.RT)
    with pytest.raises(ValueError, match=r"K must have shape \(3, 3\)"):
        project_points(torch.zeros(4, 3), torch.eye(4), cam.RT)
    with pytest.raises(ValueError, match=r"RT must have shape \(3, 4\)"):
        project_points(torch.zeros(4, 3), cam.K, torch.eye(3))
    with pytest.raises(ValueError, match=r"Camera.K must have shape \(3, 3\)"):
        Camera(K=torch.eye(4), RT=cam.RT, width=16, height=16)
    with pytest.raises(ValueError, match="no faces"):
        render_view(trimesh.Trimesh(), cam)
    with pytest.raises(ValueError, match="Camera"):
        render_view(torus, {"K": cam.K})
    with pytest.raises(ValueError, match="fov_deg"):
        sample_camera(0, fov_deg=180.0)
    with pytest.raises(ValueError, match="distance"):
        sample_camera(0, distance=0.0)
