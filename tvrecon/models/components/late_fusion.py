"""Late fusion of trained touch classifiers: their class probabilities combined (beyond the paper).

The paper's classifier reads N tactile images stacked on channels; it sees each touch's texture and outline in the pad's
frame but not where on the object the touch was made. The contact cloud
(:class:`~tvrecon.models.components.contact_cloud.ContactCloudClassifier`) reads where the touches landed as 3D
contact patches but not their images. Their errors differ (on ``cls_paper`` the paper's classifier loses the spoon and
the wrench, the cloud the key and the fork), so a sample one of them gets wrong the other often gets right. This
module asks every member on the same touches and combines their answers; the members are trained on their own and
stay as they are (nothing here is trained).

Rules, over M members with class probabilities ``p_m = softmax(logits_m)``:

- ``"mean_prob"``: ``log(1/M sum_m p_m)``, the average of the probabilities (a member that is sure and wrong is
  outvoted only by a member that is as sure);
- ``"mean_log_prob"``: ``log_softmax(1/M sum_m log p_m)``, the normalised geometric mean (a class any member rules out
  stays ruled out).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["FUSION_RULES", "LateFusionClassifier"]

#: the ways of combining the members' class probabilities (see the module docstring)
FUSION_RULES = ("mean_prob", "mean_log_prob")


class LateFusionClassifier(nn.Module):
    """Several trained classifiers asked on the same touches, their class probabilities combined.

    Args:
        members: the classifiers, each ``forward(*inputs) -> (B, C)`` logits over the same C classes, reading the
            per-touch batch keys named by its ``touch_inputs`` (default ``("tactile",)``).
        rule: one of :data:`FUSION_RULES`.

    Attributes:
        touch_inputs: every key a member reads, in first-seen order (what the classification module hands over).
        num_touches: the fewest touches any member takes at most (its input check).
    """

    def __init__(self, members: Sequence[nn.Module], rule: str = "mean_prob") -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"late fusion needs at least 2 classifiers, got {len(members)}")
        if rule not in FUSION_RULES:
            raise ValueError(f"unknown fusion rule {rule!r}; available: {list(FUSION_RULES)}")
        self.members = nn.ModuleList(members)
        self.rule = rule
        keys: list[str] = []
        for member in members:
            keys += [k for k in getattr(member, "touch_inputs", ("tactile",)) if k not in keys]
        self.touch_inputs = tuple(keys)
        # where each member's inputs sit among the fused inputs
        self._slots = [[keys.index(k) for k in getattr(m, "touch_inputs", ("tactile",))] for m in members]
        limits = [int(m.num_touches) for m in members if getattr(m, "num_touches", None) is not None]
        self.num_touches = min(limits) if limits else None

    def member_log_probs(self, *inputs: Tensor) -> Tensor:
        """Every member's class log-probabilities.

        Args:
            inputs: the per-touch tensors named by :attr:`touch_inputs`, each (B, N, ...).

        Returns:
            (M, B, C) float.
        """
        if len(inputs) != len(self.touch_inputs):
            raise ValueError(f"expected {len(self.touch_inputs)} inputs {list(self.touch_inputs)}, got {len(inputs)}")
        out = [F.log_softmax(m(*[inputs[i] for i in slots]), dim=-1) for m, slots in zip(self.members, self._slots)]
        classes = {int(x.shape[-1]) for x in out}
        if len(classes) != 1:
            raise ValueError(f"the fused classifiers answer over different numbers of classes: {sorted(classes)}")
        return torch.stack(out)

    def forward(self, *inputs: Tensor) -> Tensor:
        """The fused answer: (B, C) float log-probabilities (argmax = the class), from inputs (B, N, ...)."""
        log_p = self.member_log_probs(*inputs)  # (M, B, C)
        M = log_p.shape[0]
        if self.rule == "mean_prob":
            return torch.logsumexp(log_p, dim=0) - torch.log(torch.tensor(float(M), dtype=log_p.dtype))
        return F.log_softmax(log_p.mean(0), dim=-1)
