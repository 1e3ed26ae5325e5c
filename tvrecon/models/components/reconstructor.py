"""Tactile-visual mesh reconstructor (paper section 3.3, Figure "projection").

visual ResNet-18 stage j  ->  + Agg(tactile stage i, direction) placed at the touch's pixel, for every i  ->  stage j+1
the four fused visual stages (perceptual feature)  ->  Pixel2Mesh deformer (ellipsoid 156 -> 618 -> 2466 vertices).

Modes: ``"fusion"`` (the paper's model), ``"visual_only"`` (the Pixel2Mesh baseline: no tactile branch at all) and
``"tactile_only"`` (the view is replaced by a blank, all-zeros image; the camera still places the touches).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.fusion import TactileVisualFusion, TouchPlacement, locate_touches
from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.utils.geometry import rotate_to_camera
from tvrecon.utils.shape_check import check_shape

__all__ = ["MODES", "TactileVisualReconstructor", "check_view"]

MODES = ("fusion", "visual_only", "tactile_only")


def check_view(image: Tensor, K: Tensor, RT: Tensor) -> tuple[int, int]:
    """Check a batch of views: image (B, 3, H, W), K (B, 3, 3), RT (B, 3, 4). Returns (H, W); ValueError otherwise."""
    check_shape(image, "(B, 3, H, W)", "image")
    check_shape(K, "(B, 3, 3)", "K")
    check_shape(RT, "(B, 3, 4)", "RT")
    B = image.shape[0]
    if K.shape[0] != B or RT.shape[0] != B:
        raise ValueError(f"K must be (B, 3, 3) and RT (B, 3, 4) with B={B}, got {tuple(K.shape)}, {tuple(RT.shape)}")
    return int(image.shape[2]), int(image.shape[3])


class TactileVisualReconstructor(nn.Module):
    """Two ResNet-18 branches joined by Agg blocks, feeding a Pixel2Mesh graph deformer.

    Args:
        visual_backbone: visual branch (default: a randomly initialised ``ResNet18Backbone``).
        tactile_backbone: tactile branch shared by all touches (default: a new ``ResNet18Backbone`` in the modes
            that use touches); ignored and not kept in ``visual_only`` mode.
        fusion: the Agg blocks (default ``TactileVisualFusion()`` with the backbones' channels); not kept in
            ``visual_only`` mode.
        deformer: the mesh deformer (default ``MeshDeformer()`` with the visual channels).
        mode: ``"fusion"``, ``"visual_only"`` or ``"tactile_only"``.
    """

    def __init__(
        self,
        visual_backbone: ResNet18Backbone | None = None,
        tactile_backbone: ResNet18Backbone | None = None,
        fusion: TactileVisualFusion | None = None,
        deformer: MeshDeformer | None = None,
        mode: str = "fusion",
    ) -> None:
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self.visual = visual_backbone if visual_backbone is not None else ResNet18Backbone()
        visual_channels = list(self.visual.channels)
        self.tactile: ResNet18Backbone | None = None
        self.fusion: TactileVisualFusion | None = None
        if mode != "visual_only":
            self.tactile = tactile_backbone if tactile_backbone is not None else ResNet18Backbone()
            self.fusion = (
                fusion
                if fusion is not None
                else TactileVisualFusion(tactile_channels=self.tactile.channels, visual_channels=visual_channels)
            )
            if list(self.fusion.visual_channels) != visual_channels:
                raise ValueError(
                    f"fusion.visual_channels {self.fusion.visual_channels} must match the visual backbone's "
                    f"{visual_channels}"
                )
        self.deformer = deformer if deformer is not None else MeshDeformer(feature_channels=visual_channels)

    @property
    def uses_touches(self) -> bool:
        """Whether the model reads tactile inputs."""
        return self.mode != "visual_only"

    def forward(
        self,
        image: Tensor,
        K: Tensor,
        RT: Tensor,
        tactile: Tensor | None = None,
        positions: Tensor | None = None,
        directions: Tensor | None = None,
        touch_mask: Tensor | None = None,
    ) -> dict[str, list[Tensor]]:
        """Reconstruct a mesh in camera coordinates.

        Args:
            image: (B, 3, H, W) float view (replaced by zeros in ``tactile_only`` mode).
            K: (B, 3, 3) float intrinsics; RT: (B, 3, 4) float world->camera extrinsics.
            tactile: (B, T, 3, h, w) float tactile images, or None (no touch; required in ``tactile_only``).
            positions: (B, T, 3) float world touch positions; directions: (B, T, 3) float world press directions.
            touch_mask: (B, T) bool, True = real touch (None = all real).

        Returns:
            dict of per-stage lists (s = 0, 1, 2): ``verts`` (B, V_s, 3) float camera-frame prediction,
            ``faces`` (F_s, 3) int64, ``edges`` (E_s, 2) int64, ``init_verts`` (V_s, 3) float template (ellipsoid
            at level s), ``verts_before`` (B, V_s, 3) float input of deformation block s (for the move/laplace
            terms); and ``features``: the 4 fused visual maps (B, C_j, h_j, w_j).
        """
        image_size = check_view(image, K, RT)
        if self.mode == "tactile_only":
            if tactile is None:
                raise ValueError("tactile_only mode needs tactile, positions and directions (got tactile=None)")
            image = torch.zeros_like(image)

        touches = None
        if self.uses_touches and tactile is not None:
            touches = self._encode_touches(tactile, positions, directions, touch_mask, K, RT, image_size)

        x = self.visual.stem(image)
        features = []
        for j in range(len(self.visual.stages)):
            x = self.visual.stage(j, x)
            if touches is not None:
                assert self.fusion is not None
                x = self.fusion(j, x, touches[0], touches[1], touches[2], image_size)
            features.append(x)
        out = self.deformer(features, K, image_size)
        out["features"] = features
        return out

    def _encode_touches(
        self,
        tactile: Tensor,
        positions: Tensor | None,
        directions: Tensor | None,
        touch_mask: Tensor | None,
        K: Tensor,
        RT: Tensor,
        image_size: tuple[int, int],
    ) -> tuple[list[Tensor], Tensor | None, TouchPlacement] | None:
        """Run the tactile branch on the contributing touches only (folded into the batch; shared weights).

        Returns (tactile stage maps 4 x (N, C_i, h_i, w_i), direction embedding (N, C_max) or None, placement), or
        None when no touch contributes.
        """
        assert self.tactile is not None and self.fusion is not None
        check_shape(tactile, "(B, T, 3, h, w)", "tactile")
        B, T = tactile.shape[:2]
        if positions is None or directions is None:
            raise ValueError("positions (B, T, 3) and directions (B, T, 3) are required with tactile")
        check_shape(positions, "(B, T, 3)", "positions")
        check_shape(directions, "(B, T, 3)", "directions")
        if positions.shape[:2] != (B, T) or directions.shape[:2] != (B, T):
            raise ValueError(
                f"positions and directions must have shape (B, T, 3) = ({B}, {T}, 3), got "
                f"{tuple(positions.shape)} and {tuple(directions.shape)}"
            )
        placement = locate_touches(positions, K, RT, image_size, touch_mask)
        idx = placement.touch_index  # (N,)
        if idx.numel() == 0:
            return None
        feats = self.tactile(tactile.flatten(0, 1)[idx])  # 4 x (N, C_i, h_i, w_i)
        # press directions in the camera frame (R d), the frame of the predicted mesh (see
        # tvrecon.models.components.fusion)
        dirs_cam = rotate_to_camera(directions, RT)  # (B, T, 3)
        dir_emb = self.fusion.embed_directions(dirs_cam.flatten(0, 1)[idx].to(tactile.dtype), placement.depth)
        return feats, dir_emb, placement
