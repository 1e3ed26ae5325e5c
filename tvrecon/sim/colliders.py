"""Rigid static colliders as signed distance functions in unit-domain coordinates (sdf < 0 inside).

``SphereCollider`` and ``PlaneCollider`` are analytic. ``MeshCollider`` precomputes the signed distance of a trimesh
mesh on the lattice nodes of a region (the nodes a sensor can reach) and looks it up trilinearly.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

__all__ = ["Collider", "SphereCollider", "PlaneCollider"]


@runtime_checkable
class Collider(Protocol):
    """A rigid, static body: signed distance (< 0 inside) and unit outward normal at query points."""

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) float points -> (N,) signed distance, < 0 inside."""
        ...

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) float points -> (N, 3) unit outward normal (gradient of the sdf)."""
        ...


def _check_points(points: Tensor) -> None:
    if not isinstance(points, Tensor) or points.dim() != 2 or points.shape[1] != 3:
        shape = tuple(points.shape) if isinstance(points, Tensor) else type(points).__name__
        raise ValueError(f"points must be an (N, 3) tensor, got {shape}")


def _vec3(value: Sequence[float] | Tensor | np.ndarray, name: str) -> Tensor:
    t = torch.as_tensor(np.asarray(value, dtype=np.float64) if not isinstance(value, Tensor) else value)
    if t.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {t.tolist()}")
    return t


class SphereCollider:
    """Solid sphere.

    Args:
        center: (3,) centre in domain units.
        radius: radius > 0 in domain units.
    """

    def __init__(self, center: Sequence[float] | Tensor, radius: float) -> None:
        self.center = _vec3(center, "center")
        if not float(radius) > 0:
            raise ValueError(f"radius must be > 0, got {radius}")
        self.radius = float(radius)

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N,) ``|p - c| - r``."""
        _check_points(points)
        return (points - self.center.to(points)).norm(dim=1) - self.radius

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N, 3) unit ``(p - c) / |p - c|`` (+z at the centre itself)."""
        _check_points(points)
        d = points - self.center.to(points)
        n = d.norm(dim=1, keepdim=True)
        up = torch.zeros_like(d)
        up[:, 2] = 1.0
        return torch.where(n > 0, d / torch.where(n > 0, n, torch.ones_like(n)), up)


class PlaneCollider:
    """Half-space below a plane: solid where ``(p - point) . normal < 0``.

    Args:
        point: (3,) a point on the plane.
        normal: (3,) outward normal (normalized here; must be non-zero).
    """

    def __init__(self, point: Sequence[float] | Tensor, normal: Sequence[float] | Tensor) -> None:
        self.point = _vec3(point, "point")
        n = _vec3(normal, "normal").to(torch.float64)
        norm = float(n.norm())
        if norm < 1e-12:
            raise ValueError("normal must be non-zero")
        self.n = n / norm

    def sdf(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N,) ``(p - point) . n``."""
        _check_points(points)
        return ((points - self.point.to(points)) * self.n.to(points)).sum(1)

    def normal(self, points: Tensor) -> Tensor:
        """(N, 3) -> (N, 3) the constant plane normal."""
        _check_points(points)
        return self.n.to(points).expand(points.shape[0], 3).clone()
