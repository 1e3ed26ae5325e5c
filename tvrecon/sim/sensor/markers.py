"""Marker-displacement images: a dot grid printed on the contact layer, as a camera behind the pad sees it.

Optical tactile sensors (GelSight, DIGIT, ...) print a grid of markers on the gel and track them: the dots move with
the contact layer's in-plane displacement (shear). Here the markers sit on the rest contact layer at taxel
coordinates (x = column j, y = row i, the layout of :func:`tvrecon.sim.sensor.elastic_pad.pad_lattice`), follow the
tactile image's displacement (bilinear between taxels), and are projected onto the camera behind the pad: the camera
looks along -z from the hand side with x right and y up (the orientation of ``tactile.png``), orthographic by default or
a pinhole ``camera_distance`` cells behind the contact layer (then a dot pushed towards the camera also moves away
from the image centre). Dots are drawn as soft discs.

Every function takes leading batch dimensions on the image or positions and works on any device.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["marker_grid", "marker_positions", "marker_displacements", "render_markers"]


def _check_image(image: Tensor) -> None:
    if not isinstance(image, Tensor):
        raise ValueError(f"image must be a (..., 3, H, W) displacement tensor, got {type(image).__name__}")
    check_shape(image, "(..., 3, H, W)", "image")
    if not bool(torch.isfinite(image).all()):
        raise ValueError("image contains NaN or infinite values")


def _check_points(points: Tensor, name: str, spec: str = "(..., M, 2)") -> None:
    if not isinstance(points, Tensor):
        raise ValueError(f"{name} must be a {spec} tensor of (x, y) taxel coordinates, got {type(points).__name__}")
    check_shape(points, spec, name)
    if not bool(torch.isfinite(points).all()):
        raise ValueError(f"{name} contains NaN or infinite values")


def marker_grid(resolution: tuple[int, int], spacing: float = 4.0, device: torch.device | str | None = None) -> Tensor:
    """Rest positions of a square marker grid centred on the pad.

    Args:
        resolution: (H, W) taxels of the contact layer.
        spacing: distance between neighbouring markers, in taxels (> 0).
    Returns:
        (M, 2) float32 (x, y) taxel coordinates (x = column, y = row), rows of constant y, x fastest; the markers
        lie strictly inside (0, W - 1) x (0, H - 1) when the pad is wider than the spacing.
    """
    H, W = (int(r) for r in resolution)
    if H < 1 or W < 1:
        raise ValueError(f"resolution must be (H, W) >= 1, got {resolution}")
    if not (math.isfinite(float(spacing)) and float(spacing) > 0):
        raise ValueError(f"marker spacing must be > 0 taxels, got {spacing}")
    sp = float(spacing)

    def axis(n: int) -> Tensor:
        count = max(1, math.ceil((n - 1) / sp - 1e-9))  # as many as fit strictly inside the first/last taxel
        return (n - 1) / 2 + sp * (torch.arange(count, dtype=torch.float32, device=device) - (count - 1) / 2)

    ys, xs = torch.meshgrid(axis(H), axis(W), indexing="ij")
    return torch.stack([xs, ys], -1).reshape(-1, 2)


def _sample(image: Tensor, points: Tensor) -> Tensor:
    """Bilinear (..., 3, H, W) at (M, 2) taxel points -> (..., M, 3) (edges clamped)."""
    H, W = image.shape[-2:]
    lead = image.shape[:-3]
    flat = image.reshape(-1, 3, H, W)
    scale = torch.tensor([max(W - 1, 1), max(H - 1, 1)], dtype=image.dtype, device=image.device)
    grid = (points.to(image) / scale * 2 - 1).expand(flat.shape[0], 1, -1, 2)  # (N, 1, M, 2), align_corners
    out = F.grid_sample(flat, grid, mode="bilinear", padding_mode="border", align_corners=True)  # (N, 3, 1, M)
    return out[:, :, 0].transpose(1, 2).reshape(*lead, points.shape[0], 3)


def marker_positions(
    image: Tensor, markers: Tensor, taxel_spacing: float = 0.5, camera_distance: float | None = None
) -> Tensor:
    """Where the camera sees each marker on the deformed contact layer.

    Args:
        image: (..., 3, H, W) displacement in grid cells (x shear, y shear, z normal towards the camera), e.g.
            ``TactileReading.image``.
        markers: (M, 2) rest (x, y) taxel coordinates (:func:`marker_grid`).
        taxel_spacing: grid cells between neighbouring taxels (``SensorConfig.spacing``).
        camera_distance: pinhole camera this many cells behind the rest contact layer, on the pad's axis; None =
            orthographic.
    Returns:
        (..., M, 2) image coordinates in taxels (at rest equal to ``markers``).
    """
    _check_image(image)
    _check_points(markers, "markers", "(M, 2)")
    if not float(taxel_spacing) > 0:
        raise ValueError(f"taxel_spacing must be > 0 cells, got {taxel_spacing}")
    u = _sample(image, markers)  # (..., M, 3) cells
    pos = markers.to(u) + u[..., :2] / float(taxel_spacing)
    if camera_distance is None:
        return pos
    D = float(camera_distance)
    if not (math.isfinite(D) and D > 0):
        raise ValueError(f"camera_distance must be > 0 cells or None, got {camera_distance}")
    depth = D - u[..., 2:3]  # the normal displacement moves the dot towards the camera
    if not bool((depth > 1e-6).all()):
        raise ValueError(f"a marker reached the camera (normal displacement >= camera_distance {D} cells)")
    H, W = image.shape[-2:]
    centre = torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=u.dtype, device=u.device)
    return centre + (pos - centre) * D / depth


def marker_displacements(
    image: Tensor, markers: Tensor, taxel_spacing: float = 0.5, camera_distance: float | None = None
) -> Tensor:
    """Marker motion in the camera image: :func:`marker_positions` minus the rest grid.

    Returns:
        (..., M, 2) displacement vectors (x, y) in taxels.
    """
    return marker_positions(image, markers, taxel_spacing, camera_distance) - markers.to(image)


def render_markers(
    positions: Tensor,
    resolution: tuple[int, int],
    radius: float = 1.0,
    pixels_per_taxel: int = 4,
    softness: float = 0.75,
) -> Tensor:
    """Soft-disc dot image of marker positions.

    Output pixel (r, c) covers taxel coordinates centred at ``((c + 0.5) / k - 0.5, (r + 0.5) / k - 0.5)`` with
    k = ``pixels_per_taxel``; row 0 is y = 0 (draw with ``origin="lower"`` for y up). A dot's coverage is
    ``sigmoid((radius - d) / softness)`` at distance d, overlapping dots take the maximum.

    Args:
        positions: (..., M, 2) (x, y) taxel coordinates (:func:`marker_positions`).
        resolution: (H, W) taxels of the pad. radius: dot radius in taxels (> 0).
        pixels_per_taxel: output pixels per taxel along each axis (>= 1).
        softness: edge width in output pixels (> 0).
    Returns:
        (..., H * k, W * k) coverage in [0, 1] (1 = dot), the positions' dtype and device.
    """
    _check_points(positions, "positions")
    H, W = (int(r) for r in resolution)
    k = int(pixels_per_taxel)
    if k < 1 or H < 1 or W < 1:
        raise ValueError(f"pixels_per_taxel and resolution must be >= 1, got {pixels_per_taxel} and {resolution}")
    if not float(radius) > 0 or not float(softness) > 0:
        raise ValueError(f"radius and softness must be > 0, got {radius} and {softness}")
    dev, dt = positions.device, positions.dtype if positions.is_floating_point() else torch.float32
    pos = positions.to(dt)
    ys = (torch.arange(H * k, device=dev, dtype=dt) + 0.5) / k - 0.5
    xs = (torch.arange(W * k, device=dev, dtype=dt) + 0.5) / k - 0.5
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    pix = torch.stack([gx, gy], -1).reshape(-1, 2)  # (Q, 2)
    lead, M = pos.shape[:-2], pos.shape[-2]
    flat = pos.reshape(-1, M, 2)
    out = torch.zeros(flat.shape[0], pix.shape[0], device=dev, dtype=dt)
    width = float(softness) / k
    for s in range(0, M, 64):  # chunks of markers keep the (N, m, Q) distances small
        d = torch.cdist(
            flat[:, s : s + 64], pix[None].expand(flat.shape[0], -1, -1), compute_mode="donot_use_mm_for_euclid_dist"
        )  # (N, m, Q), exact (no matmul expansion: a shifted grid must render as the shifted image)
        out = torch.maximum(out, torch.sigmoid((float(radius) - d) / width).amax(1))
    return out.reshape(*lead, H * k, W * k)
