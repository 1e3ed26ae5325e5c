"""Evaluation over K headings of a touch set (beyond the paper): a classifier trained with the touch set turned about
the up axis at random (``data.rotate_pose``) is asked K times, the set turned by ``2 pi k / K``, and the class
probabilities are averaged.

Such a classifier has learned that the heading carries no information, but it is not exactly invariant to it: one
heading's answer carries the error of that one view of the set. Averaging evenly spaced headings removes that part of
the error, as test-time augmentation does for images. Only the 3D inputs turn (contact points, normals, touch
positions and directions, :func:`tvrecon.data.pose_augment.turn_about_up`); the tactile images are in the pad's frame
and stay as they are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from tvrecon.data.pose_augment import turn_about_up

__all__ = ["TURNABLE_INPUTS", "check_headings", "heading_ensemble"]

#: per-touch inputs that are world points or directions, turned with the set
TURNABLE_INPUTS = frozenset({"patch_points", "patch_normals", "positions", "directions"})


def check_headings(headings: int, names: Sequence[str]) -> int:
    """``headings`` as an int, after checking it is >= 1 and, above 1, that the network reads a 3D input.

    Raises:
        ValueError: ``headings`` < 1, or > 1 for a network whose inputs ``names`` hold nothing to turn (the paper's
            classifier reads tactile images only: every heading would give the same answer).
    """
    k = int(headings)
    if k < 1:
        raise ValueError(f"headings must be >= 1 (1 = the set as it is), got {headings}")
    if k > 1 and not TURNABLE_INPUTS.intersection(names):
        raise ValueError(
            f"headings={k} turns the touch set's 3D inputs ({sorted(TURNABLE_INPUTS)}), but the network reads only "
            f"{list(names)}: use headings=1 with it"
        )
    return k


def heading_ensemble(
    forward: Callable[..., Tensor], inputs: Sequence[Tensor], names: Sequence[str], headings: int
) -> Tensor:
    """Log of the class probabilities averaged over ``headings`` evenly spaced turns of the touch set about +z.

    Args:
        forward: the network, ``forward(*inputs) -> (B, C)`` logits.
        inputs: per-touch tensors (B, N, ...), in the order of ``names``.
        names: the batch key of each input; those in :data:`TURNABLE_INPUTS` are (..., 3) world vectors.
        headings: K >= 1 turns, by ``2 pi k / K`` for k = 0..K-1 (k = 0: the set as it is).

    Returns:
        (B, C) float log-probabilities; with K = 1 the network's log-softmax, whose argmax is the logits' argmax.
    """
    if len(inputs) != len(names):
        raise ValueError(f"got {len(inputs)} inputs for {len(names)} names {list(names)}")
    k = check_headings(headings, names)
    turn = [name in TURNABLE_INPUTS for name in names]
    log_probs = []
    for j in range(k):
        angle = 2.0 * math.pi * j / k
        turned = [turn_about_up(x, angle) if t and j > 0 else x for x, t in zip(inputs, turn, strict=True)]
        log_probs.append(torch.log_softmax(forward(*turned), dim=-1))
    # log of the mean probability, computed stably: logsumexp over the K answers minus log K
    return torch.logsumexp(torch.stack(log_probs), dim=0) - math.log(k)
