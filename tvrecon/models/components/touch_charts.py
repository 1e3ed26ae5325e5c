"""Touch charts of the Chart-based method (Smith et al., NeurIPS 2020): a touch's local surface as a small fixed mesh.

A touch chart is a ``size x size`` grid of vertices (5 x 5 as the authors') laid over the touch's contact region in
the sensor's known pose. Two sources give the contact region's 3D points:

* ``patch``: the exact contact patch (:func:`tvrecon.sim.sensor.patch.contact_patch`; the batch's ``patch_points`` and
  ``patch_mask``, what touch geometry reads);
* ``predicted``: :class:`TouchChartPredictor`, the authors' touch branch: a U-Net predicts from the tactile image each
  pixel's height along the sensor's normal; the pixel, placed on the pad with the sensor's pose and lifted by that
  height, is a point of the local surface where the tactile image shows contact. It is trained with the authors'
  touch-chart loss, the chamfer distance between its points and the exact patch's (:mod:`tvrecon.losses.charts`).

:func:`fit_touch_charts` turns either point set into a chart: the contact points are expressed in the sensor's plane
(the pad's frame rebuilt from the press direction), a ``size x size`` grid spans their bounding box in that plane and
every grid vertex takes the 3D position of the contact point nearest to it in the plane. The authors fit their sheet
to the predicted points by gradient descent (chamfer plus an edge-length term) once, offline; taking the nearest
contact point gives a sheet through the same points at no cost per step, so the charts are rebuilt for every batch.
Either way the chart is then held fixed: the graph network reads its vertices and never moves them.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.utils.shape_check import check_shape

__all__ = ["TouchChartPredictor", "TouchChartUNet", "fit_touch_charts", "sensor_frames"]


def sensor_frames(directions: Tensor) -> Tensor:
    """Sensor frames of press directions, batched: columns (e_x, e_y, e_z) with ``e_z = -direction``.

    The in-plane axis follows the pad's rule (:func:`tvrecon.sim.sensor.elastic_pad.sensor_frame`): world x projected
    onto the contact plane, or world y where the press is within ~25 degrees of the x axis. Zero directions (padded
    touches) give the identity.

    Args:
        directions: (N, 3) float press directions (into the object).

    Returns:
        (N, 3, 3) float, world = R @ local.
    """
    check_shape(directions, "(N, 3)", "directions")
    n = directions.norm(dim=-1, keepdim=True)
    ez = torch.where(n > 1e-8, -directions / n.clamp_min(1e-8), directions.new_tensor([0.0, 0.0, 1.0]))
    x_axis, y_axis = directions.new_tensor([1.0, 0.0, 0.0]), directions.new_tensor([0.0, 1.0, 0.0])
    ref = torch.where(ez[:, :1].abs() < 0.9, x_axis, y_axis)  # (N, 3)
    ex = F.normalize(ref - (ref * ez).sum(-1, keepdim=True) * ez, dim=-1)
    ey = torch.linalg.cross(ez, ex, dim=-1)
    return torch.stack([ex, ey, ez], dim=-1)


def fit_touch_charts(
    points: Tensor, mask: Tensor, origins: Tensor, directions: Tensor, size: int = 5
) -> tuple[Tensor, Tensor]:
    """A ``size x size`` chart over each touch's contact points (see the module doc).

    Args:
        points: (N, P, 3) float world contact-layer points of N touches; mask: (N, P) bool, True where in contact.
        origins: (N, 3) float the sensors' positions; directions: (N, 3) float their press directions.
        size: vertices per side.

    Returns:
        charts (N, size^2, 3) float world vertices (row-major over the sensor's y, x; zeros for a touch without
        contact) and ok (N,) bool, whether the touch has a contact point.
    """
    check_shape(points, "(N, P, 3)", "points")
    N, P, _ = points.shape
    if mask.shape != (N, P) or mask.dtype != torch.bool:
        raise ValueError(f"mask must be a ({N}, {P}) bool tensor, got {tuple(mask.shape)} {mask.dtype}")
    if origins.shape != (N, 3) or directions.shape != (N, 3):
        raise ValueError(f"origins and directions must have shape ({N}, 3), got {tuple(origins.shape)}, "
                         f"{tuple(directions.shape)}")  # fmt: skip
    if size < 2:
        raise ValueError(f"size must be >= 2, got {size}")
    ok = mask.any(dim=1)  # (N,)
    with torch.no_grad():
        R = sensor_frames(directions.detach().float())  # (N, 3, 3)
        local = torch.einsum("npd,nde->npe", points.detach().float() - origins.detach().float()[:, None], R)[..., :2]
        big = torch.finfo(local.dtype).max
        lo = torch.where(mask[..., None], local, big).amin(dim=1)  # (N, 2)
        hi = torch.where(mask[..., None], local, -big).amax(dim=1)
        lo, hi = torch.where(ok[:, None], lo, 0.0), torch.where(ok[:, None], hi, 0.0)
        s = torch.linspace(0.0, 1.0, size, device=points.device)
        gy, gx = torch.meshgrid(s, s, indexing="ij")
        grid = torch.stack([gx, gy], dim=-1).reshape(-1, 2)  # (size^2, 2) in [0, 1]^2
        nodes = lo[:, None] + grid[None] * (hi - lo)[:, None]  # (N, size^2, 2)
        d2 = torch.cdist(nodes, local).square()  # (N, size^2, P)
        pick = d2.masked_fill(~mask[:, None, :], float("inf")).argmin(dim=2)  # (N, size^2)
    charts = torch.gather(points, 1, pick[..., None].expand(-1, -1, 3))  # (N, size^2, 3)
    return torch.where(ok[:, None, None], charts, torch.zeros_like(charts)), ok


class _DoubleConv(nn.Sequential):
    """(conv 3x3, BatchNorm, ReLU) twice: the U-Net's unit."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__(
            nn.Conv2d(c_in, c_out, 3, padding=1, bias=False),
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_out, c_out, 3, padding=1, bias=False),
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True),
        )


class TouchChartUNet(nn.Module):
    """A small U-Net (the authors' touch branch, narrower): tactile image -> one height per pixel.

    Args:
        in_channels: tactile image channels.
        channels: widths of the levels (the authors' 64 ... 1024 in five levels; three narrow ones here for CPU).
    """

    def __init__(self, in_channels: int = 3, channels: Sequence[int] = (16, 32, 64)) -> None:
        super().__init__()
        if len(channels) < 2:
            raise ValueError(f"channels needs at least two levels, got {list(channels)}")
        widths = [int(c) for c in channels]
        self.inc = _DoubleConv(in_channels, widths[0])
        self.down = nn.ModuleList([_DoubleConv(a, b) for a, b in zip(widths[:-1], widths[1:])])
        self.up = nn.ModuleList([nn.ConvTranspose2d(b, a, 2, stride=2) for a, b in zip(widths[:-1], widths[1:])])
        self.merge = nn.ModuleList([_DoubleConv(2 * a, a) for a in widths[:-1]])
        self.out = nn.Conv2d(widths[0], 1, 1)
        with torch.no_grad():  # heights start near 0 (the pad at rest), not at the O(1) of a fresh conv in world units
            self.out.weight.mul_(0.01)
            self.out.bias.zero_()

    def forward(self, x: Tensor) -> Tensor:
        """Args: x (N, C, h, w) float. Returns (N, h, w) float heights (the output layer's unit)."""
        check_shape(x, "(N, C, h, w)", "x")
        skips = [self.inc(x)]
        for down in self.down:
            skips.append(down(F.max_pool2d(skips[-1], 2)))
        y = skips.pop()
        for up, merge in zip(reversed(self.up), reversed(self.merge)):
            skip = skips.pop()
            y = up(y)
            y = F.pad(y, [0, skip.shape[-1] - y.shape[-1], 0, skip.shape[-2] - y.shape[-2]])  # odd sizes
            y = merge(torch.cat([skip, y], dim=1))
        return self.out(y)[:, 0]


class TouchChartPredictor(nn.Module):
    """The local surface of touches predicted from their tactile images (the ``predicted`` touch-chart source).

    Each pixel of the (h, w) tactile image is a point of the pad's contact layer at rest, ``(x_j, y_i, 0)`` in the
    sensor frame (the pad's lattice resampled to the image's pixels), lifted along the sensor's normal by the predicted
    height and placed with the sensor's pose: ``position + R(direction) @ (x_j, y_i, height_ij)`` (world units). The
    pixels where the normal channel exceeds ``contact_threshold`` are the contact (the authors keep the pixels that
    differ from an untouched reading; an untouched reading here is all zeros).

    Args:
        pad_resolution: (Hs, Ws) particles of the pad's contact layer (``data.sensor.resolution``).
        pad_spacing: their spacing in grid cells (``data.sensor.spacing``).
        n_grid, domain_size: the press grid (``data.press``): one cell is ``domain_size / n_grid`` world units.
        contact_threshold: normal-channel value above which a pixel is in contact (tactile image units).
        channels: widths of the U-Net.
    """

    def __init__(
        self,
        pad_resolution: Sequence[int] = (31, 31),
        pad_spacing: float = 0.5,
        n_grid: int = 64,
        domain_size: float = 6.25,
        contact_threshold: float = 0.1,
        channels: Sequence[int] = (16, 32, 64),
    ) -> None:
        super().__init__()
        if len(pad_resolution) != 2 or min(int(r) for r in pad_resolution) < 2:
            raise ValueError(f"pad_resolution must be (Hs, Ws) >= 2, got {list(pad_resolution)}")
        if not pad_spacing > 0 or int(n_grid) < 1 or not domain_size > 0:
            raise ValueError(f"need pad_spacing > 0, n_grid >= 1, domain_size > 0, got {pad_spacing}, {n_grid}, "
                             f"{domain_size}")  # fmt: skip
        self.pad_resolution = (int(pad_resolution[0]), int(pad_resolution[1]))
        self.cell = float(domain_size) / int(n_grid)
        self.pad_spacing = float(pad_spacing)
        self.contact_threshold = float(contact_threshold)
        self.unet = TouchChartUNet(3, channels)

    def lattice(self, h: int, w: int, device: torch.device) -> Tensor:
        """(h w, 2) float: the rest contact layer's (x, y) in world units at the centres of an (h, w) image's pixels."""
        Hs, Ws = self.pad_resolution

        def axis(n: int, size: int) -> Tensor:
            particle = (torch.arange(n, device=device, dtype=torch.float32) + 0.5) * size / n - 0.5  # pixel -> index
            return (particle - (size - 1) / 2) * self.pad_spacing * self.cell

        yy, xx = torch.meshgrid(axis(h, Hs), axis(w, Ws), indexing="ij")
        return torch.stack([xx, yy], dim=-1).reshape(-1, 2)

    def forward(self, tactile: Tensor, positions: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """Predicted contact points of N touches.

        Args:
            tactile: (N, 3, h, w) float tactile images; positions, directions: (N, 3) float world sensor poses.

        Returns:
            points (N, h w, 3) float world (differentiable in the U-Net) and mask (N, h w) bool, the contact pixels.
        """
        check_shape(tactile, "(N, 3, h, w)", "tactile")
        N, _, h, w = tactile.shape
        if positions.shape != (N, 3) or directions.shape != (N, 3):
            raise ValueError(f"positions and directions must have shape ({N}, 3), got {tuple(positions.shape)}, "
                             f"{tuple(directions.shape)}")  # fmt: skip
        height = self.unet(tactile).reshape(N, h * w, 1)  # (N, hw, 1)
        xy = self.lattice(h, w, tactile.device)[None].expand(N, -1, -1).to(height.dtype)  # (N, hw, 2)
        local = torch.cat([xy, height], dim=-1)  # (N, hw, 3) sensor frame
        R = sensor_frames(directions.to(height.dtype))  # (N, 3, 3)
        points = positions.to(height.dtype)[:, None] + local @ R.transpose(1, 2)
        mask = (tactile[:, 2] > self.contact_threshold).reshape(N, h * w)
        return points, mask
