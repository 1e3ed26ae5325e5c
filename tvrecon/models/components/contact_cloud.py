"""Contact-cloud classifier: a PointNet over the touches' 3D contact patches (beyond the paper).

The paper's classifier reads tactile images only, so where on the object each touch was made, which a robot knows
from its arm, never reaches it. Mapped back to 3D (:func:`tvrecon.sim.sensor.patch.contact_patch`: position +
R(direction) (pad lattice + image)), the touches of an object are pieces of its surface, a partial point cloud whose
extent, curvature and arrangement are strong shape cues. This model classifies that cloud: up to ``points_per_touch``
contact points of every touch (:func:`tvrecon.models.components.touch_geometry.select_patch_points`), centred on their
mean (the object's position is not known), each point with its surface normal through a shared MLP, pooled over all
points by their maximum and mean (PointNet, Qi et al. 2017: order-invariant, any number of touches and points), then a
small MLP head. Trained with the touch set turned about the up axis at random (``data.rotate_pose``), it cannot use the
library's canonical heading.

``image_features=True`` adds the touch-set branch (:class:`~tvrecon.models.components.touch_set.TouchSetClassifier`'s
shared ResNet-18 per tactile image, mean + max pooled) to the pooled cloud features before the head, for the shear and
fine texture the cloud does not hold. ``points_per_touch=1`` keeps one contact point per touch: the where-it-touched
control (position and surface normal only, no patch shape).

``patch_tokens=True`` also encodes every touch's patch in its own frame first (PointNet++'s set abstraction, Qi et
al. 2017b, with the touches as the groups): its points centred on the patch's own mean through a second shared MLP,
max-pooled over the patch, then joined with where the patch lies (its mean, relative to the cloud's) and its mean
normal into one token per touch; the tokens are max + mean pooled beside the points. The plain PointNet sees each
point alone and pools all touches at once, so the shape of one patch (two tines side by side, a smooth bowl, a key's
teeth) reaches it only mixed with every other patch's.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from tvrecon.models.components.backbone import load_resnet18
from tvrecon.models.components.set_pool import masked_max_mean, real_touches
from tvrecon.models.components.touch_geometry import select_patch_points
from tvrecon.utils.shape_check import check_shape

__all__ = ["ContactCloudClassifier"]


def _block(inputs: int, outputs: int) -> list[nn.Module]:
    """Linear map, layer norm, ReLU: (..., inputs) -> (..., outputs)."""
    return [nn.Linear(inputs, outputs), nn.LayerNorm(outputs), nn.ReLU()]


class ContactCloudClassifier(nn.Module):
    """PointNet over the contact points of N touches (+ optional per-touch image features), then an MLP head.

    Args:
        num_classes: output classes (35).
        num_touches: the most touches a sample may have (input check only).
        points_per_touch: contact points kept per touch (spread evenly over its contact area; 1 = where it touched).
        width: features per point after the shared MLP.
        dropout: dropout in the head.
        image_features: add the pooled features of a shared ResNet-18 over the tactile images.
        pretrained: cached ImageNet weights for that ResNet-18 if available (never downloads).
        patch_tokens: add one token per touch from its patch encoded in its own frame (see the module docstring).
    """

    #: batch keys the classification module hands to :meth:`forward`, per touch, in this order
    touch_inputs = ("tactile", "patch_points", "patch_normals", "patch_mask")

    def __init__(
        self,
        num_classes: int = 35,
        num_touches: int = 10,
        points_per_touch: int = 64,
        width: int = 256,
        dropout: float = 0.3,
        image_features: bool = False,
        pretrained: bool = False,
        patch_tokens: bool = False,
    ) -> None:
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"num_classes must be >= 2, got {num_classes}")
        if num_touches < 1:
            raise ValueError(f"num_touches must be >= 1, got {num_touches}")
        if points_per_touch < 1 or width < 1:
            raise ValueError(f"points_per_touch and width must be >= 1, got {points_per_touch} and {width}")
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        self.num_classes = num_classes
        self.num_touches = num_touches
        self.points_per_touch = points_per_touch
        # layer norm after every linear map: without it the MLP sat near chance for the first ~200 steps and reached
        # 67% at 10 touches in 1,500 steps, with it 76% (lr 3e-3; the docs' issue-12 section has the runs)
        self.point_mlp = nn.Sequential(*_block(6, 64), *_block(64, 128), *_block(128, width))
        pooled = 2 * width
        self.patch_mlp: nn.Module | None = None
        self.token_mlp: nn.Module | None = None
        if patch_tokens:
            # a narrower MLP than the points' (128 features): it runs over the same points, so it doubles a step's cost
            self.patch_mlp = nn.Sequential(*_block(6, 64), *_block(64, 128))
            self.token_mlp = nn.Sequential(*_block(128 + 6, width), *_block(width, width))
            pooled += 2 * width
        self.trunk: nn.Module | None = None
        if image_features:
            trunk, _ = load_resnet18(pretrained)
            pooled += 2 * trunk.fc.in_features
            trunk.fc = nn.Identity()
            self.trunk = trunk
        #: whether the tactile images are read (else only their shape is checked; their size does not matter)
        self.reads_images = self.trunk is not None
        self.head = nn.Sequential(*_block(pooled, 256), nn.Dropout(dropout), nn.Linear(256, num_classes))

    def forward(
        self,
        tactile: Tensor,
        patch_points: Tensor,
        patch_normals: Tensor,
        patch_mask: Tensor,
        touch_mask: Tensor | None = None,
    ) -> Tensor:
        """Classify an object from its touches.

        Args:
            tactile: (B, N, 3, h, w) float tactile images (read only with ``image_features``).
            patch_points: (B, N, Q, 3) float contact-layer points (world frame, any heading).
            patch_normals: (B, N, Q, 3) float their outward surface normals.
            patch_mask: (B, N, Q) bool, True where the pad touched.
            touch_mask: (B, N) bool, True = real touch (None = all real); every sample needs one real touch.

        Returns:
            (B, num_classes) float logits, invariant to the order of the touches and to a shift of the object.
        """
        check_shape(patch_points, "(B, N, Q, 3)", "patch_points")
        B, N = patch_points.shape[:2]
        if N > self.num_touches:
            raise ValueError(f"got N={N} touches but the classifier takes at most num_touches={self.num_touches}")
        check_shape(tactile, "(B, N, 3, h, w)", "tactile")
        if tactile.shape[:2] != (B, N):
            raise ValueError(f"tactile must have B, N = {B}, {N} like patch_points, got {tuple(tactile.shape)}")
        touch_mask = real_touches(touch_mask, B, N, patch_points.device)
        cloud = select_patch_points(patch_points, patch_normals, patch_mask, touch_mask, self.points_per_touch)
        m = cloud.mask.to(cloud.points.dtype)[..., None]  # (B, P, 1)
        centre = (cloud.points * m).sum(1, keepdim=True) / m.sum(1, keepdim=True).clamp_min(1.0)  # (B, 1, 3)
        x = torch.cat([cloud.points - centre, cloud.normals], dim=-1)  # (B, P, 6)
        pooled = [masked_max_mean(self.point_mlp(x), cloud.mask)]  # (B, 2 width)
        if self.patch_mlp is not None and self.token_mlp is not None:
            pooled.append(self._patch_tokens(cloud.points, cloud.normals, cloud.mask, centre, B, N))
        if self.trunk is not None:
            feats = self.trunk(tactile.flatten(0, 1)).view(B, N, -1)  # (B, N, 512)
            pooled.append(masked_max_mean(feats, touch_mask))
        return self.head(torch.cat(pooled, dim=1))

    def _patch_tokens(self, points: Tensor, normals: Tensor, mask: Tensor, centre: Tensor, B: int, N: int) -> Tensor:
        """One token per touch from its patch in its own frame, max + mean pooled over the touches that felt.

        Args:
            points, normals: (B, N * m, 3) float, the selected contact points of N touches (m each, touch-major).
            mask: (B, N * m) bool, True for a real contact point.
            centre: (B, 1, 3) float, the cloud's mean.

        Returns:
            (B, 2 width) float.
        """
        assert self.patch_mlp is not None and self.token_mlp is not None
        m = points.shape[1] // N
        pts, nrm, msk = points.view(B, N, m, 3), normals.view(B, N, m, 3), mask.view(B, N, m)
        w = msk.to(pts.dtype)[..., None]  # (B, N, m, 1)
        count = w.sum(2).clamp_min(1.0)  # (B, N, 1)
        mean = (pts * w).sum(2) / count  # (B, N, 3): where the patch lies
        normal = (nrm * w).sum(2) / count  # (B, N, 3)
        local = torch.cat([pts - mean[:, :, None], nrm], dim=-1)  # (B, N, m, 6)
        felt = msk.any(2)  # (B, N): touches without contact have no token
        shape = self.patch_mlp(local).masked_fill(~msk[..., None], float("-inf")).amax(2)  # (B, N, 128): the max
        shape = torch.where(felt[..., None], shape, torch.zeros_like(shape))  # no -inf into the token MLP
        tokens = self.token_mlp(torch.cat([shape, mean - centre, normal], dim=-1))  # (B, N, width)
        return masked_max_mean(tokens, felt)
