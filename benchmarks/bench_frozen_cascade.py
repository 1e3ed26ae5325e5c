"""Cost of a training step of ``touch_cascade`` with its visual path fixed (``freeze=``), against the joint cascade.

``train.py experiment=touch_cascade init_from=<visual run> 'freeze=[net.visual,net.deformer.stages]'`` trains touch
geometry's deformer on a trained, fixed Pixel2Mesh (``tvrecon/train/warm_start.py``). This script times, in one
process on the same synthetic batch (``bench_train_step.synthetic_batch``: the ``small`` / ``paper_cpu`` shapes,
B = 8 views of 128 px, T = 10 touches of 64 px maps, plus contact patches of 31 x 31 points), one optimizer step of

* visual only (Pixel2Mesh alone),
* ``touch_cascade`` trained jointly (both paths learn; the touch path reads the visual one detached),
* ``touch_cascade`` with ``net.visual`` and ``net.deformer.stages`` frozen by ``FreezeParameters``, the callback of
  ``freeze=`` (no gradient, eval mode; AdamW skips the parameters without a gradient),

and prints the ratios, the share of parameters trained, and checks that a step with a non-zero learning rate leaves
every frozen entry (weights and BatchNorm statistics) as it was.

    .venv/bin/python benchmarks/bench_frozen_cascade.py [--threads 1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_train_step import build_module, synthetic_batch, time_steps, train_step  # noqa: E402

from tvrecon.models.lit_recon import ReconstructionModule  # noqa: E402
from tvrecon.train.warm_start import FreezeParameters  # noqa: E402

FROZEN = ("net.visual", "net.deformer.stages")


def with_patches(batch: dict, q: int = 31 * 31, seed: int = 1) -> dict:
    """``batch`` plus contact patches of the ``paper_cpu`` pad's size (Q = 31 x 31 points a touch): points spread
    around each touch's position on its sphere, the sphere's normals, about half of each patch in contact."""
    g = torch.Generator().manual_seed(seed)
    B, T = batch["touch_mask"].shape
    radius = batch["points"].norm(dim=-1)[:, :1, None]  # (B, 1, 1): the sphere of each sample
    around = batch["positions"][:, :, None] + 0.1 * radius[..., None] * torch.randn(B, T, q, 3, generator=g)
    points = torch.nn.functional.normalize(around, dim=-1) * radius[..., None]  # (B, T, Q, 3) on the sphere
    return {
        **batch,
        "patch_points": points,
        "patch_normals": torch.nn.functional.normalize(points, dim=-1),
        "patch_mask": torch.rand(B, T, q, generator=g) < 0.5,
    }


def freeze(module: ReconstructionModule, prefixes: tuple[str, ...] = FROZEN) -> FreezeParameters:
    """Fix the modules under ``prefixes`` with train.py's own ``freeze=`` callback, as at the start of a fit and of
    every training batch (no gradient, eval mode)."""
    module.train()
    callback = FreezeParameters(prefixes)
    callback.freeze_before_training(module)
    callback.on_train_batch_start(None, module, None, 0)
    return callback


def frozen_entries_unchanged(module: ReconstructionModule, batch: dict) -> bool:
    """One step at lr 1e-3 in train mode with the frozen parts put back in eval: are their entries untouched?"""
    freeze(module)
    names = [n for n in module.state_dict() if n.startswith(FROZEN)]
    before = {n: module.state_dict()[n].clone() for n in names}
    opt = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=1e-3)
    train_step(module, opt, batch)
    after = module.state_dict()
    return all(torch.equal(before[n], after[n]) for n in names)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    ap.add_argument("--repeats", type=int, default=3, help="timed steps per variant (best is reported)")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    batch = with_patches(synthetic_batch())
    print(f"batch B=8 T=10 128px view 64px tactile, threads={torch.get_num_threads()}")

    visual = build_module("visual_only")
    joint = build_module("touch_cascade")
    fixed = build_module("touch_cascade")
    fixed.load_state_dict(joint.state_dict())
    freeze(fixed)
    trainable = sum(p.numel() for p in fixed.parameters() if p.requires_grad)
    total = sum(p.numel() for p in fixed.parameters())

    t_visual, t_joint, t_fixed = (min(time_steps(m, batch, args.repeats)[0]) for m in (visual, joint, fixed))
    print(f"visual only:                 step {t_visual:.2f} s")
    print(f"touch_cascade, joint:        step {t_joint:.2f} s  ({t_joint / t_visual:.2f}x visual only)")
    print(
        f"touch_cascade, visual fixed: step {t_fixed:.2f} s  ({t_fixed / t_visual:.2f}x visual only, "
        f"{t_fixed / t_joint:.2f}x joint); {trainable:,} of {total:,} parameters trained ({trainable / total:.0%})"
    )
    unchanged = frozen_entries_unchanged(build_module("touch_cascade"), batch)
    print(f"frozen entries (weights, BatchNorm statistics) unchanged by a step at lr 1e-3: {unchanged}")
    if not unchanged:
        raise SystemExit("a frozen entry moved: FreezeParameters does not keep the visual path fixed")


if __name__ == "__main__":
    main()
