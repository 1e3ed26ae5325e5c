"""The reconstruction batch as the model and its tests see it: ground truth in the camera frame, the first k touches,
the contact-patch keys, and the touch controls (the batch with its touches' content replaced).

Batch keys and shapes: ``docs/reference/batch-schema.md``.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor

from tvrecon.utils.geometry import rotate_to_camera, world_to_camera
from tvrecon.utils.shape_check import check_shape

__all__ = ["PATCH_KEYS", "TOUCH_CONTROLS", "control_batch", "gt_to_camera", "keep_first_touches"]

PATCH_KEYS = ("patch_points", "patch_normals", "patch_mask")
TOUCH_CONTROLS = ("other", "blank")  # test modes with the touches' content replaced (touch_controls)


def gt_to_camera(points: Tensor, normals: Tensor, RT: Tensor) -> tuple[Tensor, Tensor]:
    """Map ground-truth surface points and normals from the world (object) frame to the camera frame.

    Args:
        points: (B, N, 3) float world points.
        normals: (B, N, 3) float world unit normals.
        RT: (B, 3, 4) float world->camera ``[R|t]``.

    Returns:
        points (B, N, 3) ``R x + t`` and normals (B, N, 3) ``R n``, float.
    """
    check_shape(points, "(B, N, 3)", "points")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {tuple(points.shape)}, got {tuple(normals.shape)}")
    check_shape(RT, "(B, 3, 4)", "RT")
    if RT.shape[0] != points.shape[0]:
        raise ValueError(f"RT must have shape (B, 3, 4) with B={points.shape[0]}, got {tuple(RT.shape)}")
    return world_to_camera(points, RT), rotate_to_camera(normals, RT)


def keep_first_touches(touch_mask: Tensor, k: int | Tensor) -> Tensor:
    """Keep the first ``k`` valid touches of each sample.

    Args:
        touch_mask: (B, T) bool, True for real touches.
        k: touches to keep (0 masks every touch out): one int for the batch, or a (B,) integer tensor per sample.

    Returns:
        (B, T) bool mask with at most k (or k[b]) True per row.
    """
    check_shape(touch_mask, "(B, T)", "touch_mask")
    if touch_mask.dtype != torch.bool:
        raise ValueError(f"touch_mask must be a (B, T) bool tensor, got {touch_mask.dtype}")
    if isinstance(k, Tensor):
        if k.shape != (touch_mask.shape[0],) or k.is_floating_point() or k.dtype == torch.bool:
            raise ValueError(
                f"per-sample k must be a ({touch_mask.shape[0]},) integer tensor, got {tuple(k.shape)} {k.dtype}"
            )
        if bool((k < 0).any()):
            raise ValueError(f"k must be >= 0, got {k.tolist()}")
        limit = k.to(touch_mask.device).unsqueeze(1)  # (B, 1)
    else:
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k}")
        limit = k
    rank = touch_mask.long().cumsum(dim=1)  # (B, T): 1-based index among valid touches
    return touch_mask & (rank <= limit)


def control_batch(batch: Mapping[str, Tensor], control: str) -> dict[str, Tensor] | None:
    """The batch with its touches' content replaced (positions and masks kept), None if it cannot be.

    Args:
        batch: collated sample dict with ``tactile`` (B, T, 3, h, w) and ``directions`` (B, T, 3).
        control: ``"other"`` (the next sample's tactile images and directions; None for B = 1) or ``"blank"``
            (zero tactile images, own directions). The contact patches (``patch_*``, when present) follow the
            content: ``"other"`` takes the next sample's (its world points: the other object's surface), and
            ``"blank"`` has no contact point (a blank image is the pad at rest: nothing touched).
    """
    out = dict(batch)
    if control == "other":
        if batch["tactile"].shape[0] < 2:
            return None
        out["tactile"] = batch["tactile"].roll(-1, dims=0)
        out["directions"] = batch["directions"].roll(-1, dims=0)
        for key in PATCH_KEYS:
            if key in batch:
                out[key] = batch[key].roll(-1, dims=0)
    elif control == "blank":
        out["tactile"] = torch.zeros_like(batch["tactile"])
        if "patch_mask" in batch:
            out["patch_mask"] = torch.zeros_like(batch["patch_mask"])
    else:
        raise ValueError(f"control must be one of {TOUCH_CONTROLS}, got {control!r}")
    return out
