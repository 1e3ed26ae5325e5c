"""What the touches change inside the paper's fusion model (a diagnostic, ``eval.py fusion_share_batches=N``).

The Agg blocks add each touch's embedding to the 3x3 region of the visual feature map at the touch's position, at
every visual stage (paper section 3.3, the dense multi-scale fusion). Whether the model reads its touches then comes
down to how large that addition is against the visual features it is added to, and how much of the map it reaches.
Per visual stage j, over the evaluated samples:

- ``added_to_visual``: ``||F_j(with touches) - F_j(visual)|| / ||F_j(visual)||`` over the pixels the touches reach
  (Frobenius norms over channels and pixels);
- ``pixels_reached``: the share of the map's pixels (per sample) that the touches change.

And at the output: ``mesh_moved``, the mean distance between each final vertex with the touches and without them
(camera frame; objects have a max extent of 1), next to ``mesh_scale``, the mean distance of the no-touch mesh's
vertices from its centroid.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import torch
from torch import Tensor, nn

from tvrecon.models.recon_batch import keep_first_touches

__all__ = ["fusion_share"]


@torch.no_grad()
def fusion_share(module: nn.Module, batches: Iterable[Mapping[str, Any]], touches: int) -> dict[str, Any]:
    """Measure the touches' share of the fused visual features of a fusion model over ``batches``.

    Args:
        module: a :class:`~tvrecon.models.lit_recon.ReconstructionModule` whose ``net.fusion`` holds the Agg blocks,
            called as ``module(batch, touch_mask)``.
        batches: collated reconstruction batches (image, K, RT, tactile, positions, directions, touch_mask).
        touches: the first ``touches`` valid touches of every sample are used (as the test's tv@k mode).

    Returns:
        ``{"touches": k, "samples": n, "stages": {j: {"added_to_visual", "pixels_reached"}}, "mesh_moved",
        "mesh_scale"}``, floats.

    Raises:
        ValueError: the model has no fusion (visual only, touch geometry), ``touches`` < 1, or no batch was given.
    """
    fusion = getattr(getattr(module, "net", None), "fusion", None)
    if fusion is None:
        raise ValueError(
            "fusion_share measures the Agg blocks of the paper's fusion model (experiment=full and its ablations); "
            f"this model ({type(getattr(module, 'net', module)).__name__}) has none"
        )
    if touches < 1:
        raise ValueError(f"touches must be >= 1, got {touches}")
    sums: dict[int, list[float]] = {}  # stage -> [added^2, visual^2, pixels reached, pixels]

    def hook(_mod: nn.Module, args: tuple[Any, ...], out: Tensor) -> None:
        stage, visual = int(args[0]), args[1]  # TactileVisualFusion.forward(stage, visual, ...)
        added = out - visual  # (B, C, h, w)
        reached = added.abs().sum(1) > 0  # (B, h, w)
        r = reached[:, None].expand_as(visual)
        s = sums.setdefault(stage, [0.0, 0.0, 0.0, 0.0])
        s[0] += float(added[r].double().square().sum())
        s[1] += float(visual[r].double().square().sum())
        s[2] += float(reached.sum())
        s[3] += float(reached.numel())

    device = next(module.parameters()).device
    was_training = module.training
    module.eval()
    moved = scale = 0.0
    samples = 0
    try:
        for batch in batches:
            batch = {k: v.to(device) if isinstance(v, Tensor) else v for k, v in batch.items()}
            mask = keep_first_touches(batch["touch_mask"], touches)
            plain = module(batch, None)["verts"][-1]  # (B, V, 3), no hook call: no touch, no fusion
            handle = fusion.register_forward_hook(hook)
            try:
                touched = module(batch, mask)["verts"][-1]
            finally:
                handle.remove()
            moved += float((touched - plain).norm(dim=-1).mean(1).sum())
            scale += float((plain - plain.mean(1, keepdim=True)).norm(dim=-1).mean(1).sum())
            samples += plain.shape[0]
    finally:
        module.train(was_training)
    if samples == 0:
        raise ValueError("fusion_share needs at least one batch")
    stages = {
        str(j): {
            "added_to_visual": math.sqrt(s[0] / s[1]) if s[1] > 0 else 0.0,
            "pixels_reached": s[2] / s[3] if s[3] > 0 else 0.0,
        }
        for j, s in sorted(sums.items())
    }
    return {
        "touches": int(touches),
        "samples": samples,
        "stages": stages,
        "mesh_moved": moved / samples,
        "mesh_scale": scale / samples,
    }
