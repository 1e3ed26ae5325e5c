"""Touch geometry's deformer run on the Pixel2Mesh answer (beyond the paper).

Two earlier answers to "touch geometry answers a view alone worse than Pixel2Mesh" (``docs/notes/touch-geometry.md``):

* :class:`~tvrecon.models.components.touch_geometry.TouchGeometryDeformer` reads the touches in every deformation
  block: 0.57x visual only with 10 touches, but 1.27x with none (the same blocks serve both answers);
* :class:`~tvrecon.models.components.touch_residual.TouchResidualDeformer` keeps the Pixel2Mesh path apart and adds a
  small correction (3 G-ResNet blocks of 128, reading only the visual hidden feature): no touch = Pixel2Mesh exactly,
  but it learned a small correction only (0.96x).

Here the touch path is touch geometry's own deformer, block for block, started on the visual path's meshes instead of
the ellipsoid. At stage ``s`` a :class:`~tvrecon.models.components.touch_geometry.TouchDeformationBlock` (by default
the widths and block count of the visual path) reads at each touched vertex ``y = x_s + delta``:

    g_v = concat(h_touch (unpooled, stages > 0), h_visual, y_v, proj(f_p at y_v))   (paper eq. 13, two hiddens)

plus the touch features of ``y`` injected before every G-ResNet block, and moves ``y`` by an offset (eq. 15) that
starts at zero. The correction ``delta`` and ``h_touch`` go to the next level by edge-midpoint unpooling. The gate
(a sample without a contact point gets exactly the visual mesh) and ``detach_visual`` (the visual path and the
backbone learn from their own loss only, so with no touch the model answers what the visual-only baseline answers) are
:class:`TouchResidualDeformer`'s.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from torch import Tensor, nn

from tvrecon.models.components.ellipsoid import unpool_features
from tvrecon.models.components.touch_geometry import (
    FEATURES_PER_SCALE,
    TouchDeformationBlock,
    TouchPoints,
    touch_features,
)
from tvrecon.models.components.touch_residual import TouchResidualDeformer, zero_offset

__all__ = ["TouchCascadeDeformer"]


class TouchCascadeDeformer(TouchResidualDeformer):
    """Pixel2Mesh deformer, then a touch-geometry deformer that moves each stage's visual mesh under the touches.

    Args:
        sigmas: length scales of :func:`touch_features` (object units; objects have max extent 1).
        touch_hidden: width of the touch path's graph convs (None: the visual path's ``hidden``).
        touch_blocks: G-ResNet blocks per touch stage (None: the visual path's ``num_blocks``).
        detach_visual: the touch path reads the visual meshes, hidden features and image features without sending
            gradients back, so the visual path (and the backbone) learn from their own loss only.
        deformer_args: :class:`MeshDeformer`'s arguments (feature_channels, hidden, num_blocks, ...).
    """

    def __init__(
        self,
        sigmas: Sequence[float] = (0.02, 0.08, 0.3),
        touch_hidden: int | None = None,
        touch_blocks: int | None = None,
        detach_visual: bool = True,
        **deformer_args: Any,
    ) -> None:
        super().__init__(sigmas, touch_hidden, touch_blocks, detach_visual, **deformer_args)
        self._carry: Tensor | None = None  # the touch path's hidden feature of the stage before, in this forward

    def _touch_path(self, hidden: int, blocks: int) -> nn.ModuleList:
        """One :class:`TouchDeformationBlock` per stage with a zero offset conv (untrained: the visual meshes)."""
        first = self.stages[0]
        visual_hidden = first.conv_in.self_linear.out_features
        perceptual = first.conv_in.self_linear.in_features - 3
        touch_channels = FEATURES_PER_SCALE * len(self.sigmas)
        stages = nn.ModuleList(
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
        for block in stages:
            zero_offset(block.conv_out)
        return stages

    def _touch_offset(self, s: int, h_visual: Tensor, y: Tensor, delta: Tensor, touch: TouchPoints) -> Tensor:
        """Stage ``s``: g_v = concat(h_touch, h_visual, y_v, proj(f_p at y_v)) through touch geometry's block.

        Args / Returns: as :meth:`TouchResidualDeformer._touch_offset`; (B, V_s, 3) float offset.
        """
        assert self._view is not None, "TouchCascadeDeformer._touch_offset runs inside forward only"
        features, K, image_size = self._view
        if s == 0:
            self._carry = None
        elif self._carry is not None:
            self._carry = unpool_features(self._carry, self.template.parent_edges(s))
        pooled = self.pool.sample(y, K, features, image_size)  # (B, V_s, sum C): the image at the touched vertices
        parts = [h_visual, y, pooled] if self._carry is None else [self._carry, h_visual, y, pooled]
        new_y, self._carry = self.touch_stages[s](
            parts,
            y,
            self.template.edges(s),
            self._level_neighbours(s, y.shape[0]),
            touch_features(y, touch, self.sigmas),
        )
        if s == self.num_stages - 1:
            self._carry = None  # nothing of this forward outlives it
        return new_y - y
