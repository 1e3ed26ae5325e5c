"""Touch geometry as a residual on the Pixel2Mesh visual path (beyond the paper).

:class:`~tvrecon.models.components.touch_geometry.TouchGeometryDeformer` feeds the touch features into every
deformation block, so the same blocks must answer a view with touches and a view alone; trained that way it answered a
view alone worse than Pixel2Mesh (15.30 against 12.93 x1e-3 on ``small`` with the paper's touches,
``docs/notes/touch-geometry.md``), and more touch-free samples did not help. Here the two answers are kept apart:

* the **visual path** is Pixel2Mesh unchanged (:class:`~tvrecon.models.components.gcn.MeshDeformer`'s blocks, paper
  eq. 13-15), trained by its own loss on every sample (``ReconstructionModule(visual_loss_weight=...)`` reads
  ``out["visual"]``);
* a **touch path** adds a correction ``delta_s`` to every stage's visual mesh: at stage ``s`` a small G-ResNet reads
  the visual block's hidden feature ``f_v``, the unpooled correction of the stage before and the touch features
  (:func:`~tvrecon.models.components.touch_geometry.touch_features`) at the corrected vertices, and adds an offset.
  Its last conv starts at zero, so an untrained touch path changes nothing.

A sample without any contact point gets exactly the visual path's mesh (the correction is gated off), so with no touch
the model *is* Pixel2Mesh. With ``detach_visual`` (default) the touched meshes' loss does not reach the visual path:
the view-only answer is trained exactly as the visual-only baseline's.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from tvrecon.models.components.ellipsoid import unpool_features
from tvrecon.models.components.gcn import GraphConv, GraphInput, GResBlock, MeshDeformer, NeighbourOperator
from tvrecon.models.components.touch_geometry import FEATURES_PER_SCALE, TouchPoints, touch_features

__all__ = ["TouchCorrectionBlock", "TouchResidualDeformer", "zero_offset"]


def zero_offset(conv: GraphConv) -> GraphConv:
    """``conv`` with all weights zeroed, in place: an offset conv that starts at zero, so an untrained touch path
    leaves the visual mesh as it is."""
    with torch.no_grad():
        conv.self_linear.weight.zero_()
        conv.self_linear.bias.zero_()
        conv.neighbour_linear.weight.zero_()
    return conv


class TouchCorrectionBlock(nn.Module):
    """One stage of the touch path: ``(f_v, delta_v, touch features) -> graph conv -> G-ResNet blocks -> offset``.

    Args:
        in_features: visual hidden channels + 3 (the incoming correction) + touch feature channels.
        hidden: width of the graph convs.
        num_blocks: G-ResNet blocks.
        aggregate: neighbour aggregation (``"mean"`` or ``"sum"``, see :class:`GraphConv`).
    """

    def __init__(self, in_features: int, hidden: int = 128, num_blocks: int = 3, aggregate: str = "mean") -> None:
        super().__init__()
        self.conv_in = GraphConv(in_features, hidden, aggregate)
        self.blocks = nn.ModuleList([GResBlock(hidden, aggregate) for _ in range(num_blocks)])
        self.conv_out = zero_offset(GraphConv(hidden, 3, aggregate))

    def forward(self, g: Tensor, edges: Tensor, neighbours: Tensor | NeighbourOperator) -> Tensor:
        """Args: g (B, V, C_in) float; edges (E, 2) int64; neighbours (B*V, B*V) sparse or a ``NeighbourOperator``.

        Returns: (B, V, 3) float offset to add to the stage's corrected mesh.
        """
        h = F.relu(self.conv_in(g, edges, neighbours))
        for block in self.blocks:
            h = block(h, edges, neighbours)
        return self.conv_out(h, edges, neighbours)


class TouchResidualDeformer(MeshDeformer):
    """Pixel2Mesh deformer plus a touch path that corrects each stage's mesh near the touches' contact points.

    Args:
        sigmas: length scales of :func:`touch_features` (object units; objects have max extent 1).
        touch_hidden: width of the touch path's graph convs.
        touch_blocks: G-ResNet blocks per touch-path stage.
        detach_visual: the touch path reads the visual path's meshes and features without sending gradients back, so
            the visual path learns only from its own loss.
        deformer_args: :class:`MeshDeformer`'s arguments (feature_channels, hidden, num_blocks, ...).

    Subclasses give the touch path other stages through :meth:`_touch_path` and :meth:`_touch_offset`
    (:class:`~tvrecon.models.components.touch_cascade.TouchCascadeDeformer`); the visual path, the gate and the
    carried correction stay here.
    """

    reads_touch_points = True  # forward(features, K, image_size, touch: TouchPoints | None)

    def __init__(
        self,
        sigmas: Sequence[float] = (0.02, 0.08, 0.3),
        touch_hidden: int | None = 128,
        touch_blocks: int | None = 3,
        detach_visual: bool = True,
        **deformer_args: Any,
    ) -> None:
        super().__init__(**deformer_args)  # the visual path first: its initial weights are the baseline's
        if not sigmas or any(not float(s) > 0 for s in sigmas):
            raise ValueError(f"sigmas must be positive length scales, got {list(sigmas)}")
        first = self.stages[0]
        hidden = first.conv_in.self_linear.out_features if touch_hidden is None else int(touch_hidden)
        blocks = len(first.blocks) if touch_blocks is None else int(touch_blocks)
        if hidden < 1 or blocks < 0:
            raise ValueError(f"need touch_hidden >= 1 and touch_blocks >= 0, got {hidden} and {blocks}")
        self.sigmas = [float(s) for s in sigmas]
        self.detach_visual = bool(detach_visual)
        self.touch_stages = self._touch_path(hidden, blocks)
        self._hidden: list[Tensor] = []  # the visual blocks' hidden features of the forward in progress
        self._view: tuple[list[Tensor], Tensor, tuple[int, int]] | None = None  # (features, K, image_size)

    def _touch_path(self, hidden: int, blocks: int) -> nn.ModuleList:
        """One :class:`TouchCorrectionBlock` per stage, reading (visual hidden, carried correction, touch features)."""
        visual_hidden = self.stages[0].conv_in.self_linear.out_features
        touch_channels = FEATURES_PER_SCALE * len(self.sigmas)
        return nn.ModuleList(
            [
                TouchCorrectionBlock(visual_hidden + 3 + touch_channels, hidden, blocks, self.aggregate)
                for _ in range(self.num_stages)
            ]
        )

    def _touch_offset(self, s: int, h_visual: Tensor, y: Tensor, delta: Tensor, touch: TouchPoints) -> Tensor:
        """Stage ``s``'s offset of the touched mesh.

        Args:
            s: stage; h_visual: (B, V_s, hidden) the visual block's hidden feature; y: (B, V_s, 3) the visual stage's
                mesh plus ``delta``; delta: (B, V_s, 3) the correction carried in; touch: the contact points.

        Returns: (B, V_s, 3) float offset (before the per-sample gate).
        """
        g = torch.cat([h_visual, delta, touch_features(y, touch, self.sigmas)], dim=-1)
        return self.touch_stages[s](g, self.template.edges(s), self._level_neighbours(s, y.shape[0]))

    def _deform(
        self, s: int, block: nn.Module, g: GraphInput, x: Tensor, edges: Tensor, neighbours: NeighbourOperator
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
        """Deform the ellipsoid under the view, then correct every stage's mesh under the touches.

        Args:
            features, K, image_size: as :meth:`MeshDeformer.forward`.
            touch: camera-frame contact points (B, P, 3) with normals and mask, or None (no touch).

        Returns:
            as :meth:`MeshDeformer.forward` for the corrected meshes (per stage ``verts`` (B, V_s, 3), ``verts_before``
            the stage's input: the visual input plus the unpooled correction), plus ``visual``: the visual path's own
            output dict (what the model answers without a touch).
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
        has = touch.mask.any(1).to(visual["verts"][0].dtype)[:, None, None]  # (B, 1, 1): samples with contact
        maps = [f.detach() if self.detach_visual else f for f in features]
        self._view = (maps, K, image_size)  # read by _touch_offset during this forward only
        out["verts"], out["verts_before"] = [], []
        delta: Tensor | None = None
        try:
            for s in range(self.num_stages):
                x_before, x_after, h = visual["verts_before"][s], visual["verts"][s], hidden[s]
                if self.detach_visual:
                    x_before, x_after, h = x_before.detach(), x_after.detach(), h.detach()
                if delta is None:
                    delta = torch.zeros_like(x_after)
                else:
                    delta = unpool_features(delta, self.template.parent_edges(s))
                out["verts_before"].append(x_before + delta)  # the stage's input: visual input + incoming correction
                delta = delta + has * self._touch_offset(s, h, x_after + delta, delta, touch)
                out["verts"].append(x_after + delta)
        finally:
            self._view = None
        return out
