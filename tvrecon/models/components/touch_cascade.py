"""Touch geometry's deformer run on the Pixel2Mesh answer (beyond the paper).

Two earlier answers to "touch geometry answers a view alone worse than Pixel2Mesh" (``docs/table3-paper-touches.md``):

* :class:`~tvrecon.models.components.touch_geometry.TouchGeometryDeformer` reads the touches in every deformation
  block: 0.57x visual only with 10 touches, but 1.27x with none (the same blocks serve both answers);
* :class:`~tvrecon.models.components.touch_residual.TouchResidualDeformer` keeps the Pixel2Mesh path apart and adds a
  small correction (3 G-ResNet blocks of 128, reading only the visual hidden feature): no touch = Pixel2Mesh exactly,
  but it learned a small correction only (0.96x).

Here the touch path is touch geometry's own deformer, block for block, started on the visual path's meshes instead of
the ellipsoid. At stage ``s`` a :class:`~tvrecon.models.components.touch_geometry.TouchDeformationBlock` (the widths
and block count of the visual path) reads at each touched vertex ``y = x_s + delta``:

    g_v = concat(h_touch (unpooled, stages > 0), h_visual, y_v, proj(f_p at y_v))   (paper eq. 13, two hiddens)

plus the touch features of ``y`` injected before every G-ResNet block, and moves ``y`` by an offset (eq. 15) that
starts at zero. The correction ``delta`` is carried to the next level by edge-midpoint unpooling. A sample without a
contact point gets exactly the visual mesh; with ``detach_visual`` the visual path (backbone and Pixel2Mesh blocks) is
trained by its own loss only, so with no touch the model answers what the visual-only baseline answers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor, nn

from tvrecon.models.components.ellipsoid import unpool_features
from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.models.components.touch_geometry import (
    FEATURES_PER_SCALE,
    TouchDeformationBlock,
    TouchPoints,
    touch_features,
)

__all__ = ["TouchCascadeDeformer"]


class TouchCascadeDeformer(MeshDeformer):
    """Pixel2Mesh deformer, then a touch-geometry deformer that moves each stage's visual mesh under the touches.

    Args:
        sigmas: length scales of :func:`touch_features` (object units; objects have max extent 1).
        touch_hidden: width of the touch path's graph convs (None: the visual path's ``hidden``).
        touch_blocks: G-ResNet blocks per touch stage (None: the visual path's ``num_blocks``).
        detach_visual: the touch path reads the visual meshes, hidden features and image features without sending
            gradients back, so the visual path (and the backbone) learn from their own loss only.
        deformer_args: :class:`MeshDeformer`'s arguments (feature_channels, hidden, num_blocks, ...).
    """

    reads_touch_points = True  # forward(features, K, image_size, touch: TouchPoints | None)

    def __init__(
        self,
        sigmas: Sequence[float] = (0.02, 0.08, 0.3),
        touch_hidden: int | None = None,
        touch_blocks: int | None = None,
        detach_visual: bool = True,
        **deformer_args: Any,
    ) -> None:
        super().__init__(**deformer_args)  # the visual path first: its initial weights are the baseline's
        if not sigmas or any(not float(s) > 0 for s in sigmas):
            raise ValueError(f"sigmas must be positive length scales, got {list(sigmas)}")
        first = self.stages[0]
        visual_hidden, visual_blocks = first.conv_in.self_linear.out_features, len(first.blocks)
        perceptual = first.conv_in.self_linear.in_features - 3
        hidden = visual_hidden if touch_hidden is None else int(touch_hidden)
        blocks = visual_blocks if touch_blocks is None else int(touch_blocks)
        if hidden < 1 or blocks < 0:
            raise ValueError(f"need touch_hidden >= 1 and touch_blocks >= 0, got {hidden} and {blocks}")
        self.sigmas = [float(s) for s in sigmas]
        self.detach_visual = bool(detach_visual)
        touch_channels = FEATURES_PER_SCALE * len(self.sigmas)
        self.touch_stages = nn.ModuleList(
            [
                TouchDeformationBlock(
                    (hidden if s > 0 else 0) + visual_hidden + 3 + perceptual,
                    touch_channels,
                    hidden,
                    blocks,
                    self.aggregate,
                )
                for s in range(self.num_stages)
            ]
        )
        with torch.no_grad():  # zero offsets at the start: an untrained touch path leaves the visual meshes as they are
            for block in self.touch_stages:
                block.conv_out.self_linear.weight.zero_()
                block.conv_out.self_linear.bias.zero_()
                block.conv_out.neighbour_linear.weight.zero_()
        self._hidden: list[Tensor] = []  # the visual blocks' hidden features of the forward in progress

    def _deform(
        self, s: int, block: nn.Module, g: Tensor, x: Tensor, edges: Tensor, neighbours: Tensor
    ) -> tuple[Tensor, Tensor]:
        """The plain Pixel2Mesh block; its hidden feature is kept for the touch path."""
        new_x, hidden = block(g, x, edges, neighbours)
        self._hidden.append(hidden)
        return new_x, hidden

    def forward(  # type: ignore[override]
        self,
        features: Sequence[Tensor],
        K: Tensor,
        image_size: tuple[int, int],
        touch: TouchPoints | None = None,
    ) -> dict[str, Any]:
        """Deform the ellipsoid under the view, then move every stage's mesh under the touches.

        Args:
            features: float visual maps (B, C_j, h_j, w_j); K: (B, 3, 3); image_size: (H, W).
            touch: camera-frame contact points (B, P, 3) with normals and mask, or None (no touch).

        Returns:
            as :meth:`MeshDeformer.forward` for the touched meshes (per stage ``verts`` (B, V_s, 3), ``verts_before``
            the stage's input: the visual input plus the correction carried in), plus ``visual``: the visual path's
            own output dict (what the model answers without a touch).
        """
        self._hidden = []
        try:
            visual = super().forward(features, K, image_size)
            hidden = self._hidden
        finally:
            self._hidden = []
        out: dict[str, Any] = {k: list(v) for k, v in visual.items()}
        out["visual"] = visual
        if touch is None or not bool(touch.mask.any()):
            return out  # no contact point in the batch: the visual path's answer
        B = K.shape[0]
        has = touch.mask.any(1).to(visual["verts"][0].dtype)[:, None, None]  # (B, 1, 1): samples with contact
        maps = [f.detach() for f in features] if self.detach_visual else list(features)
        out["verts"], out["verts_before"] = [], []
        delta: Tensor | None = None
        h_touch: Tensor | None = None
        for s, block in enumerate(self.touch_stages):
            x_before, x_after, h_vis = visual["verts_before"][s], visual["verts"][s], hidden[s]
            if self.detach_visual:
                x_before, x_after, h_vis = x_before.detach(), x_after.detach(), h_vis.detach()
            if delta is None:
                delta = torch.zeros_like(x_after)
            else:
                parent = self.template.parent_edges(s)
                delta = unpool_features(delta, parent)
                h_touch = unpool_features(h_touch, parent)
            y = x_after + delta  # (B, V_s, 3): the visual stage's mesh with the correction carried in
            pooled = self.pool(y, K, maps, image_size)  # (B, V_s, sum C): the image at the touched vertices
            parts = [h_vis, y, pooled] if h_touch is None else [h_touch, h_vis, y, pooled]
            new_y, h_touch = block(
                torch.cat(parts, dim=-1),
                y,
                self.template.edges(s),
                self._level_neighbours(s, B),
                touch_features(y, touch, self.sigmas),
            )
            out["verts_before"].append(x_before + delta)
            delta = delta + has * (new_y - y)
            out["verts"].append(x_after + delta)
        return out
