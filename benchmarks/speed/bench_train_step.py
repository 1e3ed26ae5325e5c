"""Speed of one training step of the reconstruction model, against the straightforward graph conv and chamfer.

Builds the network of ``configs/model/reconstructor.yaml`` (``--mode fusion`` is the paper's full model) and times
forward + backward + AdamW step on a synthetic batch with the ``small`` preset's shapes (B = 8 views of 128 px,
T = 10 touches of 64 px tactile maps, 2,048 ground-truth points; sphere objects at the origin, camera at distance 2
on -z), twice in the same process:

* ours: ``tvrecon.models.components.gcn.GraphConv`` (neighbour sums as one sparse CSR matrix product per conv) and
  ``tvrecon.losses.chamfer.nearest_neighbors`` (argmin of ``|y|^2 - 2 x.y``, one batched matmul);
* reference: the same network and losses with ``benchmarks/reference_train.py`` swapped in for both (gather both
  ends of every edge and ``index_add``; ``torch.cdist(...).square()``).

Both start from the same weights and batch; the script prints the step times, their ratio, the deformer's share
of the step, and the difference of loss and gradients between the two. They compute the same function, up to round-off
and near-ties of the nearest-neighbour search (a point almost equidistant from two others may pick the other one,
which moves that point's chamfer and normal terms; the expanded search is the more exact one against float64).

    .venv/bin/python benchmarks/bench_train_step.py [--threads 1] [--repeats 3] [--mode fusion|visual_only]
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("PROJECT_ROOT", str(ROOT))

import hydra  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402
from reference_train import cdist_nearest_neighbors, index_add_forward  # noqa: E402

import tvrecon.losses.chamfer as chamfer_module  # noqa: E402
from tvrecon.models.components.gcn import GraphConv  # noqa: E402
from tvrecon.models.lit_recon import ReconstructionModule  # noqa: E402
from tvrecon.models.recon_batch import gt_to_camera, keep_first_touches  # noqa: E402


def synthetic_batch(B: int = 8, T: int = 10, H: int = 128, h: int = 64, N: int = 2048, seed: int = 0) -> dict:
    """A batch with the small preset's shapes: spheres of radius 0.2-0.4 at the origin seen from distance 2."""
    g = torch.Generator().manual_seed(seed)
    radius = 0.2 + 0.2 * torch.rand(B, 1, 1, generator=g)
    normals = torch.nn.functional.normalize(torch.randn(B, N, 3, generator=g), dim=-1)
    dirs = torch.nn.functional.normalize(torch.randn(B, T, 3, generator=g), dim=-1)
    f = 0.5 * H / math.tan(math.radians(45.0) / 2)
    K = torch.tensor([[f, 0.0, (H - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]]).expand(B, 3, 3).clone()
    RT = torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], dim=1).expand(B, 3, 4).clone()
    return {
        "image": torch.rand(B, 3, H, H, generator=g),
        "K": K,
        "RT": RT,
        "tactile": torch.rand(B, T, 3, h, h, generator=g),
        "positions": dirs * radius,
        "directions": -dirs,
        "touch_mask": torch.ones(B, T, dtype=torch.bool),
        "points": normals * radius,
        "normals": normals,
    }


def build_module(mode: str) -> ReconstructionModule:
    """The LightningModule of the real model config (``experiment=full`` or ``visual_only``)."""
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        cfg = compose("train", overrides=[f"experiment={'full' if mode == 'fusion' else mode}"])
    return hydra.utils.instantiate(cfg.model)


def train_step(module: ReconstructionModule, opt: torch.optim.Optimizer, batch: dict) -> float:
    """One optimizer step (forward, the Pixel2Mesh losses, backward, AdamW); returns the loss."""
    points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
    mask = None if module.modality == "visual" else keep_first_touches(batch["touch_mask"], 10)
    out = module(batch, mask)
    terms = module.compute_losses(out, points, normals)
    opt.zero_grad(set_to_none=True)
    terms["loss"].backward()
    opt.step()
    return float(terms["loss"].detach())


def time_steps(module: ReconstructionModule, batch: dict, repeats: int) -> tuple[list[float], float, list]:
    """Warm-up step, then ``repeats`` timed steps; returns (times, first loss, gradients of the first step)."""
    opt = torch.optim.AdamW(module.parameters(), lr=0.0)  # lr 0: every timed step sees the same weights
    loss = train_step(module, opt, batch)
    grads = [p.grad.detach().clone() if p.grad is not None else None for p in module.parameters()]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        train_step(module, opt, batch)
        times.append(time.perf_counter() - t0)
    return times, loss, grads


def deformer_time(module: ReconstructionModule, batch: dict) -> float:
    """Seconds of forward + backward through the mesh deformer and the losses alone (fixed image features)."""
    with torch.no_grad():
        feats = module.net(batch["image"], batch["K"], batch["RT"])["features"]
    feats = [f.detach().requires_grad_(True) for f in feats]
    points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
    size = (batch["image"].shape[2], batch["image"].shape[3])
    times = []
    for _ in range(2):  # warm-up, then timed
        t0 = time.perf_counter()
        out = module.net.deformer(feats, batch["K"], size)
        module.compute_losses(out, points, normals)["loss"].backward()
        times.append(time.perf_counter() - t0)
    return times[-1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    ap.add_argument("--repeats", type=int, default=3, help="timed steps per variant (best is reported)")
    ap.add_argument("--mode", default="fusion", choices=("fusion", "visual_only"))
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    batch = synthetic_batch()
    ours = build_module(args.mode)
    ref = copy.deepcopy(ours)
    print(f"model: {args.mode}, batch B=8 T=10 128px view 64px tactile, threads={torch.get_num_threads()}")

    t_ours, loss_ours, g_ours = time_steps(ours, batch, args.repeats)
    d_ours = deformer_time(ours, batch)
    original = GraphConv.forward, chamfer_module.nearest_neighbors
    GraphConv.forward = index_add_forward  # the reference graph convolution, same weights
    chamfer_module.nearest_neighbors = cdist_nearest_neighbors
    try:
        t_ref, loss_ref, g_ref = time_steps(ref, batch, args.repeats)
        d_ref = deformer_time(ref, batch)
    finally:
        GraphConv.forward, chamfer_module.nearest_neighbors = original
    pairs = [(a, b) for a, b in zip(g_ours, g_ref) if a is not None and b is not None]
    grad_diff = max((a - b).abs().max().item() for a, b in pairs) / max(b.abs().max().item() for _, b in pairs)
    best, best_ref = min(t_ours), min(t_ref)
    print(f"ours:      step {best:.2f} s (runs {[round(t, 2) for t in t_ours]}), deformer + losses {d_ours:.2f} s")
    print(f"reference: step {best_ref:.2f} s (runs {[round(t, 2) for t in t_ref]}), deformer + losses {d_ref:.2f} s")
    print(
        f"speed-up ours / reference: {best_ref / best:.2f}x per training step, {d_ref / d_ours:.2f}x deformer + losses"
    )
    print(
        f"same function: |loss diff| = {abs(loss_ours - loss_ref):.3g}, max |grad diff| / max |grad| = {grad_diff:.3g}"
    )


if __name__ == "__main__":
    main()
