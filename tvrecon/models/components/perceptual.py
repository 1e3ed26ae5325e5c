"""Perceptual pooling (Pixel2Mesh): multi-stage image features sampled at the projection of each mesh vertex.

Vertices (camera frame) are projected with K (kornia) and each visual stage is sampled bilinearly with
``grid_sample(align_corners=False)`` (pixel centres at integers: see ``projection.pixel_to_grid``), then the samples
are concatenated (``PerceptualPooling``). ``PerceptualPooling.sample`` returns the same features unevaluated
(``PerceptualSample``) for a graph conv to read as part of its input: sampling is linear, so the conv multiplies a map
by its weights before or after sampling, whichever order is cheaper, and samples the smallest maps as a product with
their bilinear weights (``bilinear_weights``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.models.components.projection import camera_to_pixel, pixel_to_grid

__all__ = ["DENSE_SAMPLE_PIXELS", "PerceptualPooling", "PerceptualSample", "bilinear_weights"]


class PerceptualSample(NamedTuple):
    """The perceptual part of ``g_v`` before it is sampled: the view's feature maps and where each vertex reads them.

    ``features``: float maps (B, C_j, h_j, w_j); ``grid``: (B, V, 1, 2) float ``grid_sample`` coordinates of the
    vertices. ``sample()`` gives the (B, V, sum_j C_j) features that ``PerceptualPooling`` returns; a
    ``GraphConv`` reading it as part of its input applies its weights to the small maps first where that is cheaper
    (``project``): sampling is bilinear, so ``W sample(f) = sample(W f)``.
    """

    features: Sequence[Tensor]
    grid: Tensor

    @property
    def channels(self) -> int:
        """sum_j C_j."""
        return int(sum(f.shape[1] for f in self.features))

    def sample(self) -> Tensor:
        """(B, V, sum_j C_j) float bilinear samples of every map (border padding)."""
        return torch.cat([_sample_map(f, self.grid) for f in self.features], dim=1).transpose(1, 2)

    def project(self, weight: Tensor) -> Tensor:
        """``sample() @ weight.T`` (B, V, C_out) float for weight (C_out, sum_j C_j); the same function up to round-off.

        A map of at most ``DENSE_SAMPLE_PIXELS`` pixels is sampled as a product with its (B, V, h w) bilinear weights
        (``bilinear_weights``; grid_sample's backward scatters every channel of every vertex, which costs more than the
        product on maps this small), in the cheaper order of the chain ``S (f W^T)`` or ``(S f) W^T``. Larger maps are
        sampled with ``grid_sample`` and then multiplied.
        """
        V, O = self.grid.shape[1], weight.shape[0]
        out: Tensor | None = None
        col = 0
        for f in self.features:
            C, h, w = f.shape[1], f.shape[2], f.shape[3]
            wj = weight[:, col : col + C]  # (C_out, C_j)
            col += C
            if h * w > DENSE_SAMPLE_PIXELS or min(h, w) < 2:
                term = F.linear(_sample_map(f, self.grid).transpose(1, 2), wj)
            else:
                S = bilinear_weights(self.grid, h, w)  # (B, V, h w) float32 or wider
                flat = f.flatten(2).transpose(1, 2)  # (B, h w, C_j)
                if h * w * C * O + V * h * w * O < V * h * w * C + V * C * O:  # project the map first
                    term = _weights_product(S, F.linear(flat, wj))
                else:
                    term = F.linear(_weights_product(S, flat), wj)
            out = term if out is None else out + term
        assert out is not None, "PerceptualSample has no feature map"
        return out


# maps with at most this many pixels are sampled by a product with their bilinear weights (a 128 px view's 8x8 and 4x4
# ResNet stages, a 224 px view's 7x7), larger maps by grid_sample: with the four maps of a 128 px view and a weight of
# 384 columns, forward + backward of ``project`` at 2,466 vertices took 0.30 s with 64 here, 0.29-0.43 s with 256 and
# 0.74-0.80 s with grid_sample alone (one core of an AMD EPYC, bf16 autocast)
DENSE_SAMPLE_PIXELS = 64


def bilinear_weights(grid: Tensor, height: int, width: int) -> Tensor:
    """The weights of ``grid_sample(mode="bilinear", padding_mode="border", align_corners=False)`` as a matrix.

    Args:
        grid: (B, V, 1, 2) float normalised (x, y) sample positions; height, width: the map's size (both >= 2).

    Returns:
        S (B, V, height * width) float32 (or wider), four non-zeros a row summing to 1, differentiable in ``grid``:
        ``S @ f.flatten(2).transpose(1, 2)`` equals ``grid_sample(f, grid)[..., 0].transpose(1, 2)``.
    """
    g = grid[:, :, 0, :].to(torch.promote_types(grid.dtype, torch.float32))  # (B, V, 2)
    x = (((g[..., 0] + 1.0) * width - 1.0) * 0.5).clamp(0.0, width - 1.0)  # pixel coordinates, border padding
    y = (((g[..., 1] + 1.0) * height - 1.0) * 0.5).clamp(0.0, height - 1.0)
    x0 = x.detach().floor().clamp(max=width - 2)  # left / top corner, so that the right / bottom one is inside
    y0 = y.detach().floor().clamp(max=height - 2)
    wx, wy = x - x0, y - y0  # (B, V) in [0, 1]
    base = (y0 * width + x0).long()  # (B, V)
    index = torch.stack([base, base + 1, base + width, base + width + 1], dim=-1)  # (B, V, 4)
    weights = torch.stack([(1 - wx) * (1 - wy), wx * (1 - wy), (1 - wx) * wy, wx * wy], dim=-1)  # (B, V, 4)
    S = torch.zeros(*base.shape, height * width, dtype=weights.dtype, device=weights.device)
    return S.scatter_add(2, index, weights)


def _weights_product(S: Tensor, values: Tensor) -> Tensor:
    """S (B, V, P) @ values (B, P, C) outside autocast, in S's precision (sampling weights stay float32)."""
    with torch.autocast(S.device.type, enabled=False):
        return torch.bmm(S, values.to(S.dtype))


def _sample_map(f: Tensor, grid: Tensor) -> Tensor:
    """f (B, C, h, w) float sampled at grid (B, V, 1, 2) -> (B, C, V) (bilinear, border padding).

    Sampled in the wider of the two dtypes, so a bfloat16 map (under autocast) never rounds the positions.
    """
    dtype = torch.promote_types(f.dtype, grid.dtype)
    with torch.autocast(f.device.type, enabled=False):
        return F.grid_sample(f.to(dtype), grid.to(dtype), mode="bilinear", padding_mode="border", align_corners=False)[
            ..., 0
        ]


class PerceptualPooling(nn.Module):
    """Sample multi-stage image features at the projection of each vertex (Pixel2Mesh perceptual pooling)."""

    def forward(self, verts: Tensor, K: Tensor, features: Sequence[Tensor], image_size: tuple[int, int]) -> Tensor:
        """Pool features for every vertex.

        Args:
            verts: (B, V, 3) float vertices in camera coordinates.
            K: (B, 3, 3) float intrinsics of the view.
            features: float maps (B, C_j, h_j, w_j), all covering the full (H, W) view.
            image_size: (H, W) of the view.

        Returns:
            (B, V, sum_j C_j) float; vertices projecting outside the image read the border features.
        """
        return self.sample(verts, K, features, image_size).sample()

    def sample(
        self, verts: Tensor, K: Tensor, features: Sequence[Tensor], image_size: tuple[int, int]
    ) -> PerceptualSample:
        """What ``forward`` pools, unevaluated (for a ``GraphConv`` input; arguments as ``forward``)."""
        uv = camera_to_pixel(verts, K, min_depth=1e-3)  # (B, V, 2)
        return PerceptualSample(list(features), pixel_to_grid(uv, image_size)[:, :, None, :])  # grid (B, V, 1, 2)
