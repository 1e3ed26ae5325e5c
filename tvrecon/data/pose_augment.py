"""Pose augmentation of a touch set: the whole set turned about the world's up axis (beyond the paper).

Objects stand upright (+z up, :func:`tvrecon.data.views.sample_camera`) but a robot does not know which way an
object faces. Turning every touch of a sample, its position, press direction and contact patch, by one angle about
+z gives the same object in another heading: the touches keep their relative geometry and their relation to
gravity. Training with a random heading per visit (``rotate_pose``) keeps a classifier that reads touch positions
from learning the library's canonical heading (:meth:`tvrecon.data.touches.select.TouchSelector.yaw`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["turn_about_up"]


def turn_about_up(vectors: Tensor, angle: float) -> Tensor:
    """Turn points or directions by ``angle`` radians counter-clockwise about the world +z axis (through the origin).

    Args:
        vectors: (..., 3) float world points or directions.
        angle: the turn in radians.

    Returns:
        (..., 3) tensor like ``vectors``: ``(x cos a - y sin a, x sin a + y cos a, z)``.
    """
    check_shape(vectors, "(..., 3)", "vectors")
    if not math.isfinite(float(angle)):
        raise ValueError(f"angle must be finite, got {angle}")
    c, s = math.cos(float(angle)), math.sin(float(angle))
    x, y, z = vectors.unbind(-1)
    return torch.stack([c * x - s * y, s * x + c * y, z], dim=-1)
