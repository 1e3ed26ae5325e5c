"""N-touch tactile classifier (paper section 4.2, Table 2).

The N tactile images of one object are stacked along the channel axis (3N channels) and classified by a ResNet-18
whose first convolution is widened to ``3 * num_touches`` input channels (replicating the ImageNet RGB kernel / N when
pretrained weights are cached, random otherwise). Inputs with fewer than ``num_touches`` touches are zero padded;
masked touches are zeroed, so one network serves N = 1..num_touches.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tvrecon.models.components.backbone import load_resnet18, widen_conv
from tvrecon.utils.shape_check import check_shape

__all__ = ["TactileClassifier"]


class TactileClassifier(nn.Module):
    """ResNet-18 over touches stacked along channels.

    Args:
        num_classes: output classes (35 in the paper).
        num_touches: maximum number of touches N (input channels 3N), 1..10 in the paper.
        pretrained: use cached ImageNet weights if available (never downloads).
    """

    def __init__(self, num_classes: int = 35, num_touches: int = 10, pretrained: bool = False) -> None:
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"num_classes must be >= 2, got {num_classes}")
        if num_touches < 1:
            raise ValueError(f"num_touches must be >= 1, got {num_touches}")
        self.num_touches = num_touches
        self.num_classes = num_classes
        net, loaded = load_resnet18(pretrained)
        net.conv1 = widen_conv(net.conv1, 3 * num_touches, copy_weights=loaded)
        net.fc = nn.Linear(net.fc.in_features, num_classes)
        self.net = net

    def forward(self, tactile: Tensor, touch_mask: Tensor | None = None) -> Tensor:
        """Classify an object from its touches.

        Args:
            tactile: (B, N, 3, h, w) float tactile images, N <= num_touches.
            touch_mask: (B, N) bool, True = real touch (None = all real); masked touches are zeroed.

        Returns:
            (B, num_classes) float logits.
        """
        check_shape(tactile, "(B, N, 3, h, w)", "tactile")
        B, N = tactile.shape[:2]
        if N > self.num_touches:
            raise ValueError(f"got N={N} touches but the classifier takes at most num_touches={self.num_touches}")
        if touch_mask is not None:
            if touch_mask.shape != (B, N):
                raise ValueError(f"touch_mask must have shape (B, N) = ({B}, {N}), got {tuple(touch_mask.shape)}")
            tactile = tactile * touch_mask.to(tactile.dtype)[:, :, None, None, None]
        if N < self.num_touches:
            pad = tactile.new_zeros(B, self.num_touches - N, *tactile.shape[2:])
            tactile = torch.cat([tactile, pad], dim=1)
        return self.net(tactile.flatten(1, 2))  # (B, 3N, h, w) -> (B, num_classes)
