"""Pinhole projection helpers shared by the fusion placement and the mesh deformer.

Convention (OpenCV, same as ``tvrecon.data.views``): ``RT`` (3,4) maps world to camera coordinates, the camera looks
along +z with y down; ``K`` (3,3) maps camera coordinates to pixels ``(u, v)`` with u to the right, v down and pixel
centres at integer coordinates, so an ``H x W`` image covers ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``. The world->camera
transform itself (``world_to_camera``, ``rt_to_matrix``) lives in ``tvrecon.utils.geometry`` and is re-exported here.

Feature maps of a CNN stage with stride ``s`` cover the same field of view as the image: image pixel coordinate ``u``
maps to feature coordinate ``(u + 0.5) * w / W - 0.5`` (``pixel_to_feature``), which is also the mapping that
``torch.nn.functional.grid_sample(..., align_corners=False)`` assumes (``pixel_to_grid``).
"""

from __future__ import annotations

import torch
from kornia.geometry.camera.perspective import project_points
from torch import Tensor

from tvrecon.utils.geometry import world_to_camera
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "camera_to_pixel",
    "in_image",
    "pixel_to_feature",
    "pixel_to_grid",
    "project",
    "project_with_depth",
]


def camera_to_pixel(points_cam: Tensor, K: Tensor, min_depth: float = 1e-6) -> Tensor:
    """Project camera-frame points to pixel coordinates with kornia.

    Points with ``z < min_depth`` (behind or on the camera plane) are projected as if at ``z = min_depth`` so the
    result stays finite; use ``project_with_depth`` to know which ones are in front.

    Args:
        points_cam: (B, N, 3) float camera coordinates.
        K: (B, 3, 3) float intrinsics.
        min_depth: smallest depth used in the division.

    Returns:
        (B, N, 2) float pixel coordinates ``(u, v)``.
    """
    check_shape(points_cam, "(B, N, 3)", "points_cam")
    check_shape(K, "(B, 3, 3)", "K")
    if K.shape[0] != points_cam.shape[0]:
        raise ValueError(f"K must have shape (B, 3, 3) with B={points_cam.shape[0]}, got {tuple(K.shape)}")
    points_cam = points_cam.to(torch.promote_types(points_cam.dtype, torch.float32))  # pixels need float32 or more
    z = points_cam[..., 2:].clamp(min=min_depth)
    safe = torch.cat([points_cam[..., :2], z], dim=-1)
    n = safe.shape[1]
    Kn = K.to(safe.dtype)[:, None].expand(-1, n, -1, -1)  # (B, N, 3, 3)
    with torch.autocast(safe.device.type, enabled=False):  # bfloat16 would put a 128 px view's pixels 0.5 px apart
        return project_points(safe, Kn)


def project_with_depth(points: Tensor, K: Tensor, RT: Tensor) -> tuple[Tensor, Tensor]:
    """Project world points to pixels and also return their camera depth.

    Args:
        points: (B, N, 3) float world coordinates.
        K: (B, 3, 3) float intrinsics.
        RT: (B, 3, 4) float world->camera extrinsics.

    Returns:
        uv (B, N, 2) float pixel coordinates and z (B, N) float depth (<= 0 means behind the camera).
    """
    cam = world_to_camera(points, RT)
    return camera_to_pixel(cam, K), cam[..., 2]


def project(points: Tensor, K: Tensor, RT: Tensor) -> Tensor:
    """Project world points to pixel coordinates (OpenCV convention).

    Args:
        points: (B, N, 3) float world coordinates.
        K: (B, 3, 3) float intrinsics.
        RT: (B, 3, 4) float world->camera extrinsics.

    Returns:
        (B, N, 2) float pixel coordinates ``(u, v)``.
    """
    return project_with_depth(points, K, RT)[0]


def in_image(uv: Tensor, height: int, width: int) -> Tensor:
    """Whether pixel coordinates fall inside an ``height x width`` image (OpenCV: ``[-0.5, W - 0.5)``).

    Args:
        uv: (..., 2) float pixel coordinates.

    Returns:
        (...) bool.
    """
    u, v = uv[..., 0], uv[..., 1]
    return (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)


def pixel_to_feature(uv: Tensor, image_size: tuple[int, int], feature_size: tuple[int, int]) -> Tensor:
    """Scale image pixel coordinates to a feature map's pixel coordinates (pixel centres at integers in both).

    Args:
        uv: (..., 2) float image pixel coordinates.
        image_size: (H, W) of the image.
        feature_size: (h, w) of the feature map.

    Returns:
        (..., 2) float feature-map pixel coordinates.
    """
    (H, W), (h, w) = image_size, feature_size
    scale = uv.new_tensor([w / W, h / H])
    return (uv + 0.5) * scale - 0.5


def pixel_to_grid(uv: Tensor, image_size: tuple[int, int]) -> Tensor:
    """Normalise pixel coordinates to ``grid_sample``'s [-1, 1] range for ``align_corners=False``.

    Args:
        uv: (..., 2) float image pixel coordinates.
        image_size: (H, W) of the image.

    Returns:
        (..., 2) float normalised coordinates (x, y); -1 and 1 are the outer image borders.
    """
    H, W = image_size
    size = uv.new_tensor([W, H])
    return (2.0 * uv + 1.0) / size - 1.0
