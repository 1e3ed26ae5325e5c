"""Training-step time of the Chart-based method against other reconstruction experiments, on one batch.

Builds each experiment's model from the real configs (``train.py``'s composition with ``data=<preset>``) and times
forward + loss + backward + Adam step on the same synthetic batch with ``paper_cpu``'s shapes (B = 8 views of 128 px,
T = 10 touches of 64 px tactile maps, 31 x 31 contact layers with ~290 contact points each, 2,048 ground-truth points;
a sphere at the origin, the camera at distance 2 on -z), every touch in use. The experiments take turns within each
repeat, so a load on the machine falls on all of them alike; compare the medians (and minima) as ratios.

    .venv/bin/python -m benchmarks.speed.bench_chart_step [--experiments chart_based full visual_only] [--threads 1]
        [--repeats 4] [--data paper_cpu]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path

import hydra
import torch
import torch.nn.functional as F
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import open_dict

from tvrecon.models.recon_batch import gt_to_camera

ROOT = Path(__file__).resolve().parents[2]
os.environ.setdefault("PROJECT_ROOT", str(ROOT))


def make_batch(B: int = 8, T: int = 10, H: int = 128, h: int = 64, pad: int = 31) -> dict[str, torch.Tensor]:
    """A paper_cpu-shaped reconstruction batch (``docs/reference/batch-schema.md``) of a sphere of radius 0.35."""
    g = torch.Generator().manual_seed(0)
    f = 0.5 * H / math.tan(math.radians(35.0) / 2)
    r = 0.35
    d = F.normalize(torch.randn(B, T, 3, generator=g), dim=-1)
    s = torch.linspace(-0.3, 0.3, pad)
    yy, xx = torch.meshgrid(s, s, indexing="ij")
    ref = torch.where(d[..., :1].abs() < 0.9, torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 1, 0]))
    ex = F.normalize(torch.linalg.cross(d, ref, dim=-1), dim=-1)
    ey = torch.linalg.cross(d, ex, dim=-1)
    layer = d[..., None, :] + xx.reshape(1, 1, -1, 1) * ex[..., None, :] + yy.reshape(1, 1, -1, 1) * ey[..., None, :]
    layer = F.normalize(layer, dim=-1) * r  # (B, T, Q, 3) on the sphere
    contact = ((xx.abs() < 0.17) & (yy.abs() < 0.17)).reshape(1, 1, -1).expand(B, T, -1)
    normals = F.normalize(torch.randn(B, 2048, 3, generator=g), dim=-1)
    return {
        "image": torch.rand(B, 3, H, H, generator=g),
        "K": torch.tensor([[f, 0.0, (H - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]]).expand(B, 3, 3).contiguous(),
        "RT": torch.cat([torch.eye(3), torch.tensor([[0.0], [0.0], [2.0]])], 1).expand(B, 3, 4).contiguous(),
        "tactile": torch.rand(B, T, 3, h, h, generator=g),
        "positions": d * r,
        "directions": -d,
        "touch_mask": torch.ones(B, T, dtype=torch.bool),
        "points": normals * r,
        "normals": normals,
        "patch_points": layer,
        "patch_normals": F.normalize(layer, dim=-1),
        "patch_mask": contact.clone(),
    }


def build(experiment: str, data: str) -> torch.nn.Module:
    """The experiment's ReconstructionModule, as train.py builds it."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        cfg = compose(config_name="train", overrides=[f"experiment={experiment}", f"data={data}"])
    with open_dict(cfg):
        cfg.paths.output_dir = str(ROOT / "logs" / "bench_chart_step")
    model = hydra.utils.instantiate(cfg.model)
    model.train()
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--experiments", nargs="+", default=["chart_based", "full", "visual_only"])
    parser.add_argument("--data", default="paper_cpu")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=4)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    batch = make_batch()
    points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
    runs = {}
    for name in args.experiments:
        model = build(name, args.data)
        runs[name] = (model, torch.optim.Adam(model.parameters(), lr=1e-5))

    def step(model: torch.nn.Module, opt: torch.optim.Optimizer) -> float:
        mask = None if model.modality == "visual" else batch["touch_mask"]
        start = time.perf_counter()
        terms = model.compute_losses(model(batch, mask), points, normals)
        opt.zero_grad()
        terms["loss"].backward()
        opt.step()
        return time.perf_counter() - start

    for model, opt in runs.values():
        step(model, opt)  # warm-up
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(args.repeats):
        for name, (model, opt) in runs.items():
            times[name].append(step(model, opt))
    base = statistics.median(times[args.experiments[-1]])
    for name, ts in times.items():
        med = statistics.median(ts)
        print(
            f"{name:24s} median {med:6.2f} s  min {min(ts):6.2f} s  ({med / base:.2f}x {args.experiments[-1]})  "
            f"[{', '.join(f'{t:.2f}' for t in ts)}]"
        )


if __name__ == "__main__":
    main()
