"""Object localization from the pybullet scene's own RGB-D + segmentation camera.

The camera renders depth and a segmentation image (pybullet's TINY renderer); :func:`depth_to_points` back-projects
the object's pixels to a world point cloud, from which :func:`tvrecon.robot.grasp.plan_top_grasp` plans the grasp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p

from tvrecon.utils.shape_check import check_shape

__all__ = ["CameraConfig", "RGBDCamera", "depth_to_points"]


@dataclass
class CameraConfig:
    """A pinhole camera looking from ``eye`` at ``target`` (world metres), ``fov`` degrees vertical."""

    eye: tuple[float, float, float] = (0.78, 0.0, 1.22)
    target: tuple[float, float, float] = (0.5, 0.02, 0.625)
    up: tuple[float, float, float] = (-1.0, 0.0, 0.0)
    fov: float = 58.0
    width: int = 256
    height: int = 256
    near: float = 0.05
    far: float = 3.0


class RGBDCamera:
    """A pybullet RGB-D + segmentation camera (TINY renderer, works headless in DIRECT mode)."""

    def __init__(self, cfg: CameraConfig | None = None, client: int = 0) -> None:
        self.cfg = cfg or CameraConfig()
        c = self.cfg
        self.client = client
        self.view = p.computeViewMatrix(c.eye, c.target, c.up, physicsClientId=client)
        self.proj = p.computeProjectionMatrixFOV(c.fov, c.width / c.height, c.near, c.far, physicsClientId=client)

    def capture(self) -> dict[str, np.ndarray]:
        """Render the scene.

        Returns:
            {"rgb": (H,W,3) uint8, "depth": (H,W) float32 metres along the optical axis,
             "seg": (H,W) int32 body unique id per pixel (-1 = background), "points": (H,W,3) float32 world}
        """
        c = self.cfg
        _, _, rgba, zbuf, seg = p.getCameraImage(
            c.width, c.height, self.view, self.proj, renderer=p.ER_TINY_RENDERER, physicsClientId=self.client
        )
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(c.height, c.width, 4)
        zbuf = np.asarray(zbuf, dtype=np.float64).reshape(c.height, c.width)
        seg = np.asarray(seg, dtype=np.int64).reshape(c.height, c.width)
        depth = c.far * c.near / (c.far - (c.far - c.near) * zbuf)
        points = depth_to_points(zbuf, self.view, self.proj)
        return {
            "rgb": rgba[..., :3].copy(),
            "depth": depth.astype(np.float32),
            "seg": seg.astype(np.int32),
            "points": points.astype(np.float32),
        }


def depth_to_points(zbuf: np.ndarray, view: tuple | list, proj: tuple | list) -> np.ndarray:
    """Back-project an OpenGL depth buffer to world points.

    Args:
        zbuf: (H,W) float depth buffer in [0,1] as returned by ``getCameraImage``.
        view, proj: the 16-float column-major matrices used for rendering.

    Returns:
        (H,W,3) float64 world coordinates of each pixel.
    """
    zbuf = np.asarray(zbuf, dtype=np.float64)
    check_shape(zbuf, "(H, W)", "zbuf")
    H, W = zbuf.shape
    V = np.asarray(view, dtype=np.float64).reshape(4, 4).T
    P = np.asarray(proj, dtype=np.float64).reshape(4, 4).T
    inv = np.linalg.inv(P @ V)
    u = (np.arange(W) + 0.5) / W * 2.0 - 1.0
    v = 1.0 - (np.arange(H) + 0.5) / H * 2.0
    x_ndc, y_ndc = np.meshgrid(u, v)  # (H,W)
    ndc = np.stack([x_ndc, y_ndc, 2.0 * zbuf - 1.0, np.ones_like(zbuf)], axis=-1)  # (H,W,4)
    world = ndc @ inv.T
    return world[..., :3] / world[..., 3:4]
