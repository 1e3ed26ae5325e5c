"""Touch-set classifier: one shared ResNet-18 per touch, pooled over the touches (beyond the paper).

The paper's classifier (:class:`~tvrecon.models.components.classifier.TactileClassifier`) stacks the N tactile images
along the channels, so its first convolution has a separate kernel for every touch slot, while the touches of an object
are an unordered set (training draws them in random order). This model encodes every touch with the same ResNet-18
trunk (3 input channels, 512 features), pools the features of the real touches by their mean and maximum (so the
result does not depend on their order or number) and classifies the pooled vector with a linear layer. Every
training touch trains the one trunk, and one model serves N = 1..num_touches.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tvrecon.models.components.backbone import load_resnet18
from tvrecon.models.components.set_pool import masked_max_mean, real_touches
from tvrecon.utils.shape_check import check_shape

__all__ = ["TouchSetClassifier"]


class TouchSetClassifier(nn.Module):
    """ResNet-18 per touch (shared weights), masked mean + max pooling over touches, linear classifier.

    Args:
        num_classes: output classes (35).
        num_touches: the most touches a sample may have (input check only: the weights do not depend on it).
        pretrained: use cached ImageNet weights for the trunk if available (never downloads).
        dropout: dropout on the pooled features before the linear layer.
    """

    def __init__(self, num_classes: int = 35, num_touches: int = 10, pretrained: bool = False, dropout: float = 0.0):
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"num_classes must be >= 2, got {num_classes}")
        if num_touches < 1:
            raise ValueError(f"num_touches must be >= 1, got {num_touches}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.num_touches = num_touches
        self.num_classes = num_classes
        trunk, _ = load_resnet18(pretrained)
        features = trunk.fc.in_features
        trunk.fc = nn.Identity()
        self.trunk = trunk
        self.head = nn.Sequential(nn.Dropout(dropout), nn.Linear(2 * features, num_classes))

    def forward(self, tactile: Tensor, touch_mask: Tensor | None = None) -> Tensor:
        """Classify an object from a set of touches.

        Args:
            tactile: (B, N, 3, h, w) float tactile images, N <= num_touches.
            touch_mask: (B, N) bool, True = real touch (None = all real); every sample needs one real touch.

        Returns:
            (B, num_classes) float logits, invariant to the order of the touches.
        """
        check_shape(tactile, "(B, N, 3, h, w)", "tactile")
        B, N = tactile.shape[:2]
        if N > self.num_touches:
            raise ValueError(f"got N={N} touches but the classifier takes at most num_touches={self.num_touches}")
        touch_mask = real_touches(touch_mask, B, N, tactile.device)
        feats = self.trunk(tactile.flatten(0, 1)).view(B, N, -1)  # (B, N, F)
        peak, mean = masked_max_mean(feats, touch_mask).chunk(2, dim=1)  # (B, F) each
        return self.head(torch.cat([mean, peak], dim=1))  # [mean, max]: the order its checkpoints were trained with
