"""Perception: back-projection against the scene's true geometry, grasp planning on synthetic clouds."""

import numpy as np
import pybullet as p
import pytest
import trimesh

from tvrecon.robot.grasp import plan_top_grasp
from tvrecon.robot.pybullet.camera import CameraConfig, RGBDCamera, depth_to_points
from tvrecon.robot.pybullet.scene import Scene, SceneConfig


def _box_cloud(w: float, l: float, h: float, yaw: float, centre=(0.5, -0.1), table=0.6, n=4000) -> np.ndarray:
    rng = np.random.default_rng(0)
    local = rng.uniform(-0.5, 0.5, size=(n, 3)) * np.array([l, w, 0.0])
    local[:, 2] = h  # the top face as a top camera sees it
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    pts = np.empty_like(local)
    pts[:, :2] = local[:, :2] @ R.T + np.asarray(centre)
    pts[:, 2] = table + h
    return pts


def test_plan_closes_across_the_narrow_side() -> None:
    yaw = 0.4
    plan = plan_top_grasp(_box_cloud(w=0.04, l=0.10, h=0.08, yaw=yaw), table_z=0.6)
    assert plan.feasible, plan.reason
    assert plan.width == pytest.approx(0.04, abs=0.003)
    assert plan.length == pytest.approx(0.10, abs=0.005)
    minor = np.array([-np.sin(yaw), np.cos(yaw), 0.0])  # the box's narrow axis
    assert abs(plan.closing_axis @ minor) > 0.99
    assert np.allclose(plan.position[:2], [0.5, -0.1], atol=0.003)
    assert plan.position[2] == pytest.approx(0.6 + 0.08 - 0.025, abs=1e-3)


def test_plan_reports_too_wide_too_small_and_unseen() -> None:
    wide = plan_top_grasp(_box_cloud(w=0.12, l=0.12, h=0.12, yaw=0.0), table_z=0.6)
    assert not wide.feasible and "too wide" in wide.reason
    tiny = plan_top_grasp(_box_cloud(w=0.004, l=0.05, h=0.05, yaw=0.0), table_z=0.6)
    assert not tiny.feasible and "too small" in tiny.reason
    unseen = plan_top_grasp(np.zeros((3, 3)), table_z=0.6)
    assert not unseen.feasible and "not found" in unseen.reason
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\), got \(10, 2\)"):
        plan_top_grasp(np.zeros((10, 2)), table_z=0.6)


def test_depth_to_points_rejects_bad_shape() -> None:
    with pytest.raises(ValueError, match=r"zbuf must have shape \(H, W\), got \(2, 2, 2\)"):
        depth_to_points(np.zeros((2, 2, 2)), [0.0] * 16, [0.0] * 16)


def test_camera_cloud_lies_on_the_object_surface() -> None:
    """Back-projected segmented pixels must lie on the true (ground-truth posed) mesh, and the plan sits on it."""
    can = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=48)
    with Scene(can, SceneConfig(object_size=0.1)) as scene:
        shot = RGBDCamera(CameraConfig(), client=scene.client).capture()
        mask = shot["seg"] == scene.object
        assert mask.sum() > 200
        pts = shot["points"][mask].astype(np.float64)
        world = scene.object_mesh_world()
        _, dist, _ = trimesh.proximity.closest_point(world, pts[::5])
        assert np.percentile(dist, 95) < 0.004  # metres
        plan = plan_top_grasp(pts, table_z=scene.cfg.table_height)
        true_xy = scene.object_pose()[0][:2]
        assert np.linalg.norm(plan.position[:2] - true_xy) < 0.006
        assert plan.width == pytest.approx(0.06, abs=0.006)
        assert plan.feasible
        # depth is metric: the table top seen straight below the camera is at the right distance
        assert shot["depth"].dtype == np.float32 and shot["rgb"].shape == (256, 256, 3)
        assert p.isConnected(scene.client)
