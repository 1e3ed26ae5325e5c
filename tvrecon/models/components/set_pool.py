"""Shared pieces of the classifiers that treat an object's touches as a set (touch-set and contact-cloud)."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["masked_max_mean", "real_touches"]


def real_touches(touch_mask: Tensor | None, B: int, N: int, device: torch.device) -> Tensor:
    """The (B, N) bool mask of real touches (all real when ``touch_mask`` is None), checked.

    Raises ValueError for a wrong shape or a sample without a real touch.
    """
    if touch_mask is None:
        return torch.ones(B, N, dtype=torch.bool, device=device)
    if touch_mask.shape != (B, N):
        raise ValueError(f"touch_mask must have shape (B, N) = ({B}, {N}), got {tuple(touch_mask.shape)}")
    if bool((touch_mask.sum(1) == 0).any()):
        raise ValueError("every sample needs at least one real touch (touch_mask has an all-False row)")
    return touch_mask.to(torch.bool)


def masked_max_mean(feats: Tensor, mask: Tensor) -> Tensor:
    """Max and mean of the features of the real elements (zeros for a row with none).

    Args:
        feats: (B, P, F) float.
        mask: (B, P) bool, True for a real element.

    Returns:
        (B, 2F) float: [max, mean].
    """
    m = mask.to(feats.dtype)[..., None]  # (B, P, 1)
    count = m.sum(1)  # (B, 1)
    mean = (feats * m).sum(1) / count.clamp_min(1.0)
    peak = feats.masked_fill(~mask[..., None], float("-inf")).amax(1)
    peak = torch.where(count > 0, peak, torch.zeros_like(peak))
    return torch.cat([peak, mean], dim=1)
