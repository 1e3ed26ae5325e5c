"""Tactile-visual fusion (paper section 3.3, Figures "projection" and "agg").

* ``AggBlock``: global average pooling (GAP) of one tactile stage's feature map, then two 1x1 convolutions, each
  followed by ReLU and BatchNorm, mapping to the channel count of the target visual stage.
* ``DirectionFFN``: one feed-forward network shared by all Agg blocks embeds the touch direction
  (3 -> hidden -> max visual channels). **Choice:** the target visual stage with ``C_j`` channels uses the first
  ``C_j`` entries of that embedding (slicing, no extra projection), so every Agg block shares the same FFN weights.
  The tactile and direction embeddings are combined by a channel-wise product.
* ``place_embeddings``: global-to-local placement. Each touch position is projected with the view's K and RT into
  the image, scaled to the visual stage's resolution, and the Agg embedding is added to every pixel of the ``k x k``
  region centred at the rounded projected pixel (truncated at the map border). Touches outside the image, behind the
  camera or masked out (``touch_mask`` False) add nothing; several touches add up (``index_add``, no python loops).
* ``TactileVisualFusion``: dense fusion (an Agg for every (tactile stage i, visual stage j) pair, 16 blocks) or
  ``single_stage`` (i = j only), with the ablation switches ``use_gap`` / ``use_direction`` / ``region``.

**Start as the visual model** (``zero_init``, default on): the scale (gamma) of each Agg block's last BatchNorm is
initialised to 0, so an untrained fusion network adds nothing to the visual maps and equals the visual-only model,
and each block's scale grows only as far as its touches lower the loss (the zero-init-residual trick of ResNets).
With ``zero_init=False`` (the default BatchNorm init, scale 1) the 16 blocks add unit-size embeddings to the visual
maps from the first step.

**Directions in the camera frame**: the mesh is predicted in the camera frame and the network never sees the
camera pose, so the FFN embeds the press direction rotated into the camera frame (``R d``), not the world one.

**Touch depth (extension, not in the paper; ``touch_depth=True``, ``experiment=touch_depth``):** the paper uses a
touch's position only to find its pixel, so the network never learns how far from the camera the touched surface
is, the one thing a single view cannot tell. With ``touch_depth`` the direction FFN also reads the touch's depth
along the camera axis (camera-frame z, world units): input ``(R d, z)`` instead of ``R d``; everything else is the
paper's model.

``no_gap`` ablation (``use_gap=False``), documented choice: the Agg block skips GAP and applies its 1x1 conv stack
to the full tactile map (N, C_j, h_i, w_i); the result (times the direction embedding, broadcast over pixels) is
resized bilinearly to the visual stage's full resolution (h_j, w_j) and added to **every** pixel of the visual map,
i.e. tactile and visual maps fused pixel by pixel with no global-to-local placement. To keep the ablation about GAP
only, the set of contributing touches is the same as with GAP: a touch adds its map only if it is unmasked, in front
of the camera and projects inside the image.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.models.components.projection import in_image, pixel_to_feature, project_with_depth
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "AggBlock",
    "DirectionFFN",
    "TactileVisualFusion",
    "TouchPlacement",
    "add_maps_everywhere",
    "locate_touches",
    "place_embeddings",
]


class _SafeBatchNorm(nn.BatchNorm2d):
    """BatchNorm2d that, in training with a single sample of 1x1 spatial size (batch statistics undefined), normalises
    with the running statistics instead of raising. Happens when a batch holds exactly one valid touch."""

    def forward(self, x: Tensor) -> Tensor:
        if self.training and x.shape[0] * x.shape[2] * x.shape[3] <= 1:
            return F.batch_norm(x, self.running_mean, self.running_var, self.weight, self.bias, False, 0.0, self.eps)
        return super().forward(x)


class AggBlock(nn.Module):
    """Aggregation block: [GAP] -> 1x1 conv -> ReLU -> BN -> 1x1 conv -> ReLU -> BN.

    Args:
        in_channels: channels of the tactile stage.
        out_channels: channels of the target visual stage.
        hidden_channels: width of the first 1x1 conv (default ``out_channels``).
        use_gap: global average pooling first (False = ``no_gap`` ablation, output keeps the tactile map's size).
        zero_init: initialise the last BatchNorm's scale to 0 (the block starts by adding nothing, see module doc).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        hidden_channels: int | None = None,
        use_gap: bool = True,
        zero_init: bool = True,
    ):
        super().__init__()
        hidden = hidden_channels or out_channels
        self.use_gap = use_gap
        self.out_channels = out_channels
        self.net = nn.Sequential(
            nn.Conv2d(in_channels, hidden, kernel_size=1),
            nn.ReLU(inplace=True),
            _SafeBatchNorm(hidden),
            nn.Conv2d(hidden, out_channels, kernel_size=1),
            nn.ReLU(inplace=True),
            _SafeBatchNorm(out_channels),
        )
        if zero_init:
            nn.init.zeros_(self.net[-1].weight)

    def forward(self, tactile: Tensor, direction_embedding: Tensor | None = None) -> Tensor:
        """Embed one tactile stage.

        Args:
            tactile: (N, C_in, h, w) float tactile feature maps of N touches.
            direction_embedding: (N, C_out) float or None (``no_direction``); multiplied channel-wise.

        Returns:
            (N, C_out) float with GAP, (N, C_out, h, w) float without.
        """
        check_shape(tactile, "(N, C, h, w)", "tactile")
        x = tactile.mean(dim=(2, 3), keepdim=True) if self.use_gap else tactile  # (N, C_in, 1, 1) with GAP
        x = self.net(x)
        if direction_embedding is not None:
            if direction_embedding.shape != (x.shape[0], self.out_channels):
                raise ValueError(
                    f"direction_embedding must have shape (N, {self.out_channels}) = ({x.shape[0]}, "
                    f"{self.out_channels}), got {tuple(direction_embedding.shape)}"
                )
            x = x * direction_embedding[:, :, None, None]
        return x.flatten(1) if self.use_gap else x


class DirectionFFN(nn.Module):
    """Direction embedding shared by all Agg blocks: Linear(3 [+1], hidden) -> ReLU -> Linear(hidden, out_channels).

    Target stages with fewer channels use the first ``C_j`` entries (slicing, see module docstring).

    Args:
        hidden: hidden width.
        out_channels: embedding width (the largest visual stage's channels).
        with_depth: a fourth input, the touch's camera-frame depth (``touch_depth`` extension).
    """

    def __init__(self, hidden: int = 128, out_channels: int = 512, with_depth: bool = False) -> None:
        super().__init__()
        self.out_channels = out_channels
        self.with_depth = with_depth
        inputs = 4 if with_depth else 3
        self.net = nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, out_channels))

    def forward(self, directions: Tensor, depth: Tensor | None = None) -> Tensor:
        """Args: directions (N, 3) float unit press directions (camera frame); depth (N,) float camera-frame depth
        of each touch (required with ``with_depth``, else ignored). Returns (N, out_channels) float."""
        check_shape(directions, "(N, 3)", "directions")
        if not self.with_depth:
            return self.net(directions)
        if depth is None or depth.shape != (directions.shape[0],):
            got = None if depth is None else tuple(depth.shape)
            raise ValueError(f"with_depth needs depth of shape (N,) = ({directions.shape[0]},), got {got}")
        return self.net(torch.cat([directions, depth[:, None].to(directions.dtype)], dim=1))


class TouchPlacement(NamedTuple):
    """Where the contributing touches land: N touches that are unmasked, in front of the camera and inside the image.

    batch_index: (N,) int64 sample of each touch; uv: (N, 2) float image pixel coordinates;
    touch_index: (N,) int64 flat index into the B * T touches; depth: (N,) float camera-frame depth (z > 0).
    """

    batch_index: Tensor
    uv: Tensor
    touch_index: Tensor
    depth: Tensor


def locate_touches(
    positions: Tensor, K: Tensor, RT: Tensor, image_size: tuple[int, int], touch_mask: Tensor | None = None
) -> TouchPlacement:
    """Project touch positions and keep the touches that can contribute (unmasked, in front, inside the image).

    Args:
        positions: (B, T, 3) float world positions of the touches.
        K: (B, 3, 3) float intrinsics; RT: (B, 3, 4) float world->camera extrinsics.
        image_size: (H, W) of the view.
        touch_mask: (B, T) bool, True = real touch (None = all real).

    Returns:
        ``TouchPlacement(batch_index (N,), uv (N, 2), touch_index (N,), depth (N,))``.
    """
    check_shape(positions, "(B, T, 3)", "positions")
    B, T = positions.shape[:2]
    if touch_mask is not None and touch_mask.shape != (B, T):
        raise ValueError(f"touch_mask must have shape (B, T) = ({B}, {T}), got {tuple(touch_mask.shape)}")
    uv, z = project_with_depth(positions, K, RT)  # (B, T, 2), (B, T)
    valid = (z > 0) & in_image(uv, *image_size)
    if touch_mask is not None:
        valid = valid & touch_mask.to(torch.bool)
    flat = valid.flatten().nonzero(as_tuple=True)[0]  # (N,)
    return TouchPlacement(flat // T, uv.flatten(0, 1)[flat], flat, z.flatten()[flat])


def place_embeddings(
    feature: Tensor,
    embedding: Tensor,
    batch_index: Tensor,
    uv: Tensor,
    image_size: tuple[int, int],
    region: int = 3,
) -> Tensor:
    """Add each touch's embedding to the ``region x region`` pixels centred at its projected pixel.

    The image pixel ``uv`` is scaled to the feature map (``pixel_to_feature``) and rounded (half up); the region is
    truncated at the map border. Contributions of several touches add up.

    Args:
        feature: (B, C, h, w) float visual feature map.
        embedding: (N, C) float embeddings of N touches.
        batch_index: (N,) int64 sample of each touch.
        uv: (N, 2) float image pixel coordinates of each touch (already filtered to visible touches).
        image_size: (H, W) of the image the pixels refer to.
        region: odd side length k of the square region (1, 3, 5, ...).

    Returns:
        (B, C, h, w) float ``feature`` plus the placed embeddings (out of place; differentiable in both).
    """
    if region < 1 or region % 2 == 0:
        raise ValueError(f"region must be an odd positive integer (1, 3, 5, ...), got {region}")
    check_shape(feature, "(B, C, h, w)", "feature")
    B, C, h, w = feature.shape
    check_shape(embedding, "(N, C)", "embedding")
    check_shape(batch_index, "(N,)", "batch_index")
    check_shape(uv, "(N, 2)", "uv")
    N = embedding.shape[0]
    if embedding.shape[1] != C or batch_index.shape[0] != N or uv.shape[0] != N:
        raise ValueError(
            f"expected embedding (N, {C}), batch_index (N,), uv (N, 2); got {tuple(embedding.shape)}, "
            f"{tuple(batch_index.shape)}, {tuple(uv.shape)}"
        )
    if N == 0:
        return feature
    centre = torch.floor(pixel_to_feature(uv, image_size, (h, w)) + 0.5).long()  # (N, 2) (x, y)
    r = region // 2
    offs = torch.arange(-r, r + 1, device=feature.device)
    dy, dx = torch.meshgrid(offs, offs, indexing="ij")
    xs = centre[:, 0:1] + dx.reshape(1, -1)  # (N, k*k)
    ys = centre[:, 1:2] + dy.reshape(1, -1)  # (N, k*k)
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)  # (N, k*k)
    flat = (batch_index[:, None] * h + ys) * w + xs  # (N, k*k) index into B*h*w
    touch = torch.arange(N, device=feature.device)[:, None].expand_as(flat)
    flat, touch = flat[inside], touch[inside]  # (M,)
    pixels = feature.permute(0, 2, 3, 1).reshape(B * h * w, C)  # (B*h*w, C)
    pixels = pixels.index_add(0, flat, embedding[touch].to(pixels.dtype))
    return pixels.reshape(B, h, w, C).permute(0, 3, 1, 2)


def add_maps_everywhere(feature: Tensor, maps: Tensor, batch_index: Tensor) -> Tensor:
    """``no_gap`` fusion: resize each touch's tactile map to the visual map and add it pixel by pixel.

    Args:
        feature: (B, C, h, w) float visual feature map.
        maps: (N, C, h_t, w_t) float tactile maps (after the Agg 1x1 convs) of N visible touches.
        batch_index: (N,) int64 sample of each touch.

    Returns:
        (B, C, h, w) float.
    """
    if maps.shape[0] == 0:
        return feature
    resized = F.interpolate(maps, size=feature.shape[-2:], mode="bilinear", align_corners=False)  # (N, C, h, w)
    return feature.index_add(0, batch_index, resized.to(feature.dtype))


class TactileVisualFusion(nn.Module):
    """Dense multi-scale tactile-visual fusion with Agg blocks.

    Args:
        tactile_channels: channels of the 4 tactile stages.
        visual_channels: channels of the 4 visual stages.
        single_stage: only fuse tactile stage i into visual stage i (otherwise every pair, 16 Agg blocks).
        region: side k of the k x k placement region (1, 3 or 5 in the paper).
        use_gap: GAP in the Agg blocks (False = ``no_gap`` ablation, see module docstring).
        use_direction: multiply by the shared direction FFN embedding (False = ``no_direction``).
        direction_hidden: hidden width of the direction FFN.
        agg_hidden: hidden width of the Agg 1x1 convs (None = the target visual stage's channels).
        zero_init: start every Agg block at zero output (see module docstring).
        touch_depth: the direction FFN also reads each touch's camera-frame depth (extension, see module docstring;
            needs ``use_direction``).
    """

    def __init__(
        self,
        tactile_channels: Sequence[int] = (64, 128, 256, 512),
        visual_channels: Sequence[int] = (64, 128, 256, 512),
        single_stage: bool = False,
        region: int = 3,
        use_gap: bool = True,
        use_direction: bool = True,
        direction_hidden: int = 128,
        agg_hidden: int | None = None,
        zero_init: bool = True,
        touch_depth: bool = False,
    ) -> None:
        super().__init__()
        if touch_depth and not use_direction:
            raise ValueError("touch_depth enters through the direction FFN: it needs use_direction=True")
        if region < 1 or region % 2 == 0:
            raise ValueError(f"region must be an odd positive integer (1, 3, 5, ...), got {region}")
        if single_stage and len(tactile_channels) != len(visual_channels):
            raise ValueError(
                f"single_stage needs as many tactile as visual stages, got {len(tactile_channels)} and "
                f"{len(visual_channels)}"
            )
        self.tactile_channels = [int(c) for c in tactile_channels]
        self.visual_channels = [int(c) for c in visual_channels]
        self.single_stage = single_stage
        self.region = region
        self.use_gap = use_gap
        self.use_direction = use_direction
        self.touch_depth = touch_depth
        self.pairs: list[tuple[int, int]] = [
            (i, j)
            for j in range(len(self.visual_channels))
            for i in range(len(self.tactile_channels))
            if not single_stage or i == j
        ]
        self.aggs = nn.ModuleDict(
            {
                f"t{i}_v{j}": AggBlock(
                    self.tactile_channels[i], self.visual_channels[j], agg_hidden, use_gap, zero_init
                )
                for i, j in self.pairs
            }
        )
        self.direction_ffn = (
            DirectionFFN(direction_hidden, max(self.visual_channels), with_depth=touch_depth) if use_direction else None
        )

    def embed_directions(self, directions: Tensor, depth: Tensor | None = None) -> Tensor | None:
        """Args: directions (N, 3) float (camera frame); depth (N,) float camera-frame depth (used with
        ``touch_depth``). Returns (N, max visual channels) float, or None without direction."""
        if self.direction_ffn is None:
            return None
        return self.direction_ffn(directions, depth)

    def forward(
        self,
        stage: int,
        visual: Tensor,
        tactile_feats: Sequence[Tensor],
        direction_embedding: Tensor | None,
        placement: TouchPlacement,
        image_size: tuple[int, int],
    ) -> Tensor:
        """Fuse every connected tactile stage into visual stage ``stage``.

        Args:
            stage: visual stage index j.
            visual: (B, C_j, h_j, w_j) float visual feature map.
            tactile_feats: 4 float tensors (N, C_i, h_i, w_i), the tactile stages of the N visible touches.
            direction_embedding: (N, max C) float from ``embed_directions`` (None without direction).
            placement: ``locate_touches`` output for the same N touches.
            image_size: (H, W) of the view.

        Returns:
            (B, C_j, h_j, w_j) float fused visual feature map.
        """
        C = self.visual_channels[stage]
        check_shape(visual, f"(B, {C}, h, w)", f"visual stage {stage}")
        n = placement.batch_index.shape[0]
        if n == 0:
            return visual
        dir_emb = direction_embedding[:, :C] if direction_embedding is not None else None  # (N, C_j)
        out = visual
        for i, j in self.pairs:
            if j != stage:
                continue
            emb = self.aggs[f"t{i}_v{j}"](tactile_feats[i], dir_emb)
            if self.use_gap:
                out = place_embeddings(out, emb, placement.batch_index, placement.uv, image_size, self.region)
            else:
                out = add_maps_everywhere(out, emb, placement.batch_index)
        return out
