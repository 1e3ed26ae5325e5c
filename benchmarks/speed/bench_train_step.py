"""Speed of one reconstruction training step: today's code and settings against the step of an earlier commit.

Builds the LightningModule of ``configs/train.yaml`` for each ``--modes`` entry (``full``: the paper's model,
``visual_only``: Pixel2Mesh, ``touch_geometry``: the deformer reading contact patches) and times forward, the
Pixel2Mesh losses, backward and an AdamW step on a synthetic batch with the ``small`` / ``paper_cpu`` shapes (B = 8
views of 128 px, T = 10 touches of 64 px tactile maps, 2,048 ground-truth points, contact patches of 31 x 31 points;
spheres at the origin, camera at distance 2 on -z), twice in the same process, alternating:

* new: today's code with the configured ``trainer.precision`` (autocast as Lightning's ``bf16-mixed`` does it:
  forward and losses, not backward), the model's ``channels_last`` and its configured optimizer;
* old: the same weights and batch with the deformer and the chamfer of ``--baseline`` (``reference_train.old_step``,
  the code read from git), float32, contiguous images, AdamW's default for-each loop.

Prints per mode the min and median of each path's step and their ratios, and checks that the two compute the same
function: loss and gradients of the first step of today's code in float32 against the old code (the nearest-neighbour
search may pick the other of two near-tied points, which moves that point's chamfer and normal terms a little), and
the loss of the mixed-precision step. ``--split`` also times today's step part by part with its GFLOP;
``--loader <preset>`` measures how long each real step waits for that preset's train loader at each ``--workers``
count (it reads the preset's cache). ``--out`` writes the figures as JSON (atomic).

    .venv/bin/python -m benchmarks.speed.bench_train_step --threads 1 --repeats 5 \
        [--modes full visual_only touch_geometry]
        [--split] [--loader paper_cpu --workers 0 1 2] [--out results/bench/train_step/<machine>-<date>.json]
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime
import json
import math
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import hydra
import torch
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig
from torch.utils.flop_counter import FlopCounterMode

from benchmarks.speed.reference_train import BASELINE, old_step
from tvrecon.losses.chamfer import chamfer_terms, nearest_neighbors
from tvrecon.losses.mesh import edge_length_loss, laplacian_loss, normal_loss
from tvrecon.models.components.ellipsoid import unpool_features
from tvrecon.models.lit_recon import ReconstructionModule
from tvrecon.models.recon_batch import gt_to_camera, keep_first_touches
from tvrecon.report.provenance import git_commit, machine
from tvrecon.utils.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[2]
os.environ.setdefault("PROJECT_ROOT", str(ROOT))

MODES = ("full", "visual_only", "touch_geometry")


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


def compose_train(mode: str, overrides: list[str] | None = None) -> DictConfig:
    """``configs/train.yaml`` with ``experiment=<mode>`` (``fusion`` is an alias of ``full``) and ``overrides``."""
    experiment = "full" if mode == "fusion" else mode
    with initialize_config_dir(config_dir=str(ROOT / "configs"), version_base="1.3"):
        return compose("train", overrides=[f"experiment={experiment}", *(overrides or [])])


def build_module(mode: str, overrides: list[str] | None = None) -> ReconstructionModule:
    """The LightningModule of the real model config (``experiment=<mode>``)."""
    return hydra.utils.instantiate(compose_train(mode, overrides).model)


def autocast(precision: str, device: str = "cpu") -> contextlib.AbstractContextManager:
    """The autocast Lightning runs the forward under for ``trainer.precision`` (``bf16-mixed`` / ``16-mixed``)."""
    if precision in ("bf16-mixed", "bf16"):
        return torch.autocast(device, dtype=torch.bfloat16)
    if precision in ("16-mixed", "16"):
        return torch.autocast(device, dtype=torch.float16)
    return contextlib.nullcontext()


def train_step(module: ReconstructionModule, opt: torch.optim.Optimizer, batch: dict, precision: str = "32") -> float:
    """One optimizer step (forward and the losses under ``precision``'s autocast, backward, AdamW); returns the loss.

    Ten touches per sample (the most the presets serve); the touch-geometry patch term as in ``training_step``.
    """
    points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
    mask = None if module.modality == "visual" else keep_first_touches(batch["touch_mask"], 10)
    with autocast(precision):
        out = module(batch, mask)
        terms = module.compute_losses(out, points, normals)
        loss = terms["loss"]
        weight = float(module.hparams.get("patch_loss_weight", 0.0))
        if weight > 0 and out.get("touch") is not None:
            from tvrecon.models.components.touch_geometry import patch_to_mesh_loss

            loss = loss + weight * sum(patch_to_mesh_loss(v, out["touch"]) for v in out["verts"])
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return float(loss.detach())


def time_steps(module: ReconstructionModule, batch: dict, repeats: int) -> tuple[list[float], float, list]:
    """Warm-up step, then ``repeats`` timed float32 steps; returns (times, first loss, gradients of the first step)."""
    opt = torch.optim.AdamW(module.parameters(), lr=0.0)  # lr 0: every timed step sees the same weights
    loss = train_step(module, opt, batch)
    grads = [p.grad.detach().clone() if p.grad is not None else None for p in module.parameters()]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        train_step(module, opt, batch)
        times.append(time.perf_counter() - t0)
    return times, loss, grads


def configured_adamw(module: ReconstructionModule) -> torch.optim.Optimizer:
    """The module's configured optimizer (``model.optimizer``, e.g. ``fused: true``) at lr 0 (fixed weights)."""
    keywords = dict(getattr(module.optimizer_factory, "keywords", {}))
    keywords["lr"] = 0.0
    return module.optimizer_factory.func(module.parameters(), **keywords)


def first_step(module: ReconstructionModule, batch: dict, precision: str = "32") -> tuple[float, list]:
    """Loss and gradients (None where a parameter gets none) of one step at lr 0."""
    opt = torch.optim.AdamW(module.parameters(), lr=0.0)
    loss = train_step(module, opt, batch, precision)
    return loss, [p.grad.detach().float().clone() if p.grad is not None else None for p in module.parameters()]


def grad_difference(a: list, b: list) -> float:
    """max |a - b| / max |b| over the parameters both have gradients for."""
    pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None]
    return max((x - y).abs().max().item() for x, y in pairs) / max(y.abs().max().item() for _, y in pairs)


def bench_mode(mode: str, batch: dict, repeats: int, precision: str, baseline: str) -> dict:
    """Old and new step of one model, alternating; returns the figures of the mode."""
    torch.manual_seed(0)
    new = build_module(mode)
    old = copy.deepcopy(new)  # before any forward: each path keeps its own neighbour operators
    old.to(memory_format=torch.contiguous_format)
    if hasattr(old, "channels_last"):
        old.channels_last = False
    check = copy.deepcopy(new)  # today's code in float32, for the same-function check
    loss_new32, grads_new32 = first_step(check, batch)
    with old_step(baseline):
        loss_old, grads_old = first_step(copy.deepcopy(old), batch)
    loss_mixed, _ = first_step(copy.deepcopy(new), batch, precision)

    opt_new = configured_adamw(new)
    opt_old = torch.optim.AdamW(old.parameters(), lr=0.0)  # 487a852's configured optimizer: AdamW's for-each loop
    train_step(new, opt_new, batch, precision)  # warm-up of both paths
    with old_step(baseline):
        train_step(old, opt_old, batch)
    t_new, t_old = [], []
    for _ in range(repeats):
        with old_step(baseline):
            t0 = time.perf_counter()
            train_step(old, opt_old, batch)
            t_old.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        train_step(new, opt_new, batch, precision)
        t_new.append(time.perf_counter() - t0)
    return {
        "mode": mode,
        "old_s": [round(t, 4) for t in t_old],
        "new_s": [round(t, 4) for t in t_new],
        "speedup_min": min(t_old) / min(t_new),
        "speedup_median": statistics.median(t_old) / statistics.median(t_new),
        "loss_old": loss_old,
        "loss_new_fp32": loss_new32,
        "loss_new_mixed": loss_mixed,
        "grad_diff_fp32": grad_difference(grads_new32, grads_old),
    }


class SparseAwareFlopCounter(FlopCounterMode):
    """``FlopCounterMode`` that counts a sparse-dense product as what it computes (2 nnz x columns), not as dense."""

    def _count_flops(self, func_packet, out, args, kwargs):
        sparse = [a for a in args if isinstance(a, torch.Tensor) and a.layout != torch.strided]
        if func_packet in (torch.ops.aten.mm, torch.ops.aten.addmm) and sparse:
            flops = 2 * sparse[0]._nnz() * out.shape[-1]
            for parent in set(self.mod_tracker.parents):
                self.flop_counts[parent][func_packet] += flops
            return out
        return super()._count_flops(func_packet, out, args, kwargs)


def measure(fn: Callable[[], object], repeats: int = 2) -> tuple[float, float]:
    """(min seconds of ``fn`` over ``repeats`` runs after a warm-up, GFLOP of one run)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    counter = SparseAwareFlopCounter(display=False)
    with counter:
        fn()
    return min(times), counter.get_total_flops() / 1e9


def leaf(t: torch.Tensor) -> torch.Tensor:
    """A detached copy that requires grad: the input of a part timed on its own."""
    return t.detach().clone().requires_grad_(t.is_floating_point())


def backward_of(out: object) -> None:
    """Backward of the sum of squares of every float tensor in ``out`` (a part's stand-in loss)."""
    tensors = [t for t in (out if isinstance(out, (list, tuple)) else [out]) if isinstance(t, torch.Tensor)]
    sum(t.float().square().sum() for t in tensors if t.requires_grad).backward()


def step_split(mode: str, batch: dict, precision: str, repeats: int = 2) -> list[dict]:
    """Today's step cut into parts, each timed forward + backward on its own (inputs detached) with its GFLOP:
    visual branch, tactile branch and Agg blocks (full), deformer per stage, losses per term (the chamfer's
    nearest-neighbour search on its own), optimizer. The parts' sum is near, not equal to, the whole step."""
    torch.manual_seed(0)
    module = build_module(mode)
    net = module.net
    points, normals = gt_to_camera(batch["points"], batch["normals"], batch["RT"])
    mask = None if module.modality == "visual" else keep_first_touches(batch["touch_mask"], 10)
    image, K, RT = batch["image"], batch["K"], batch["RT"]
    size = (image.shape[2], image.shape[3])
    rows: list[dict] = []

    def add(part: str, fn: Callable[[], object]) -> None:
        seconds, gflop = measure(fn, repeats)
        rows.append({"part": part, "seconds": round(seconds, 4), "gflop": round(gflop, 3)})

    def visual() -> None:
        with autocast(precision):
            x = net.visual.stem(image)
            feats = []
            for j in range(len(net.visual.stages)):
                x = net.visual.stage(j, x)
                feats.append(x)
        backward_of(feats)

    add("visual branch", visual)
    with torch.no_grad(), autocast(precision):
        full_out = module(batch, mask)
    features = [leaf(f.float()) for f in full_out["features"]]
    if mode in ("full", "fusion"):
        assert net.tactile is not None and net.fusion is not None
        with torch.no_grad(), autocast(precision):
            touches = net._encode_touches(batch["tactile"], batch["positions"], batch["directions"], mask, K, RT, size)
        assert touches is not None
        tactile_in = batch["tactile"].flatten(0, 1)[touches[2].touch_index]

        def tactile() -> None:
            with autocast(precision):
                out = net.tactile(tactile_in)
            backward_of(out)

        add("tactile branch", tactile)
        maps = [leaf(t.float()) for t in touches[0]]
        dir_emb = leaf(touches[1].float()) if touches[1] is not None else None
        with torch.no_grad(), autocast(precision):
            x = net.visual.stem(image)
            visual_in = []
            for j in range(len(net.visual.stages)):
                x = net.visual.stage(j, x)
                visual_in.append(leaf(x.float()))
                x = net.fusion(j, x, touches[0], touches[1], touches[2], size)

        def agg() -> None:
            with autocast(precision):
                out = [net.fusion(j, v, maps, dir_emb, touches[2], size) for j, v in enumerate(visual_in)]
            backward_of(out)

        add("Agg blocks", agg)
    deformer = net.deformer
    touch = full_out.get("touch")
    for s, block in enumerate(deformer.stages):
        x = leaf(full_out["verts_before"][s])
        hidden = None
        if s > 0:  # the previous stage's hidden feature, unpooled: rerun the stages before without gradients
            with torch.no_grad(), autocast(precision):
                hidden = stage_hidden(deformer, s, features, K, size, touch)

        def stage(s: int = s, block: torch.nn.Module = block, x: torch.Tensor = x, hidden=hidden) -> None:
            h = None if hidden is None else leaf(hidden)
            with autocast(precision):
                pooled = deformer.pool.sample(x, K, features, size)
                g = [x, pooled] if h is None else [h, x, pooled]
                if getattr(deformer, "reads_touch_points", False):
                    deformer._touch = touch if touch is not None else empty_touch(K)
                try:
                    out = deformer._deform(s, block, g, x, deformer.template.edges(s), deformer._level_neighbours(s, 8))
                finally:
                    if getattr(deformer, "reads_touch_points", False):
                        deformer._touch = None
            backward_of(out)

        add(f"deformer stage {s}", stage)
    verts = [leaf(v.float()) for v in full_out["verts"]]
    before = [v.detach().float() for v in full_out["verts_before"]]
    edges = full_out["edges"]
    add("loss: chamfer search", lambda: [nearest_neighbors(v, points) or nearest_neighbors(points, v) for v in verts])
    add("loss: chamfer", lambda: sum(chamfer_terms(v, points).loss for v in verts).backward())
    idx = [chamfer_terms(v, points).idx_xy for v in verts]
    add("loss: normal", lambda: sum(normal_loss(v, e, normals, i) for v, e, i in zip(verts, edges, idx)).backward())
    add("loss: edge", lambda: sum(edge_length_loss(v, e) for v, e in zip(verts, edges)).backward())
    add("loss: Laplacian", lambda: sum(laplacian_loss(v, e, b) for v, e, b in zip(verts, edges, before)).backward())
    opt = configured_adamw(module)
    train_step(module, opt, batch, precision)  # gradients in place and AdamW's state built
    add("optimizer (AdamW)", opt.step)
    return rows


def empty_touch(K: torch.Tensor) -> object:
    """No contact point (what ``TouchGeometryDeformer.forward`` builds for ``touch=None``)."""
    from tvrecon.models.components.touch_geometry import TouchPoints

    empty = K.new_zeros(K.shape[0], 1, 3)
    return TouchPoints(empty, empty, torch.zeros(K.shape[0], 1, dtype=torch.bool))


def stage_hidden(
    deformer: torch.nn.Module, s: int, features: list, K: torch.Tensor, size: tuple, touch
) -> torch.Tensor:
    """The hidden feature stage ``s`` reads (stage s-1's, unpooled), from a forward of the stages before it."""
    B = K.shape[0]
    x = deformer.template.verts(0).to(K.dtype)[None].expand(B, -1, -1)
    hidden = None
    reads_touch = getattr(deformer, "reads_touch_points", False)
    if reads_touch:
        deformer._touch = touch if touch is not None else empty_touch(K)
    try:
        for t in range(s):
            if t > 0:
                parent = deformer.template.parent_edges(t)
                x, hidden = unpool_features(x, parent), unpool_features(hidden, parent)
            pooled = deformer.pool.sample(x, K, features, size)
            g = [x, pooled] if hidden is None else [hidden, x, pooled]
            x, hidden = deformer._deform(
                t, deformer.stages[t], g, x, deformer.template.edges(t), deformer._level_neighbours(t, B)
            )
    finally:
        if reads_touch:
            deformer._touch = None
    return unpool_features(hidden, deformer.template.parent_edges(s))


def loader_waits(
    preset: str, workers: int, steps: int, precision: str, cache_dir: str | None = None
) -> dict[str, object]:
    """Seconds each training step waits for ``data=<preset>``'s train loader with ``workers`` workers, while the
    steps are real ``visual_only`` steps on the loaded batches (the first batch, which pays the workers' start, apart).
    """
    overrides = [f"data={preset}", f"data.num_workers={workers}"]
    if cache_dir is not None:
        overrides.append(f"paths.cache_dir={cache_dir}")
    cfg = compose_train("visual_only", overrides)
    datamodule = hydra.utils.instantiate(cfg.data)
    datamodule.setup("fit")
    module = hydra.utils.instantiate(cfg.model)
    opt = configured_adamw(module)
    batches = iter(datamodule.train_dataloader())
    t0 = time.perf_counter()
    batch = next(batches)
    first = time.perf_counter() - t0
    waits, step_s = [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        train_step(module, opt, batch, precision)
        step_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        batch = next(batches)
        waits.append(time.perf_counter() - t0)
    return {
        "preset": preset,
        "workers": workers,
        "first_batch_s": round(first, 4),
        "wait_s": [round(w, 4) for w in waits],
        "step_s": [round(t, 3) for t in step_s],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    ap.add_argument("--repeats", type=int, default=3, help="timed steps per path and mode (min and median reported)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=(*MODES, "fusion"))
    ap.add_argument("--precision", default=None, help="new path's trainer.precision (default: the config's)")
    ap.add_argument("--baseline", default=BASELINE, help="commit whose deformer and chamfer the old path runs")
    ap.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    ap.add_argument("--split", action="store_true", help="also time today's step part by part, with GFLOP")
    ap.add_argument("--no-compare", action="store_true", help="skip the old-against-new timing")
    ap.add_argument("--loader", default=None, metavar="PRESET", help="also measure the train loader's wait per step")
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 2], help="loader worker counts (with --loader)")
    ap.add_argument("--cache-dir", default=None, help="paths.cache_dir for --loader (default: the config's)")
    args = ap.parse_args()
    if args.repeats < 1:
        print("error: --repeats must be >= 1", file=sys.stderr)
        sys.exit(2)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    precision = args.precision or str(compose_train("full").trainer.get("precision", "32-true"))
    batch = with_patches(synthetic_batch())
    print(
        f"batch B=8 T=10 128px view 64px tactile, threads={torch.get_num_threads()}, new precision={precision}, "
        f"old = {args.baseline}"
    )
    rows = []
    for mode in args.modes:
        row: dict = {"mode": mode}
        if args.split:
            row["split"] = step_split(mode, batch, precision)
            print(f"{mode}: today's step by part ({precision}, each forward + backward on its own)")
            for part in row["split"]:
                print(f"  {part['part']:24s} {part['seconds']:7.3f} s  {part['gflop']:8.2f} GFLOP")
            print(f"  {'sum of parts':24s} {sum(p['seconds'] for p in row['split']):7.3f} s", flush=True)
        if not args.no_compare:
            row.update(bench_mode(mode, batch, args.repeats, precision, args.baseline))
            print(
                f"{mode:15s} old min {min(row['old_s']):.2f} s  new min {min(row['new_s']):.2f} s  "
                f"speed-up min {row['speedup_min']:.2f}x median {row['speedup_median']:.2f}x  | loss old "
                f"{row['loss_old']:.6g} new fp32 {row['loss_new_fp32']:.6g} new {precision} "
                f"{row['loss_new_mixed']:.6g}  max |grad diff| / max |grad| (fp32) {row['grad_diff_fp32']:.3g}",
                flush=True,
            )
        rows.append(row)
    loader = []
    if args.loader is not None:
        for workers in args.workers:
            row = loader_waits(args.loader, workers, args.repeats, precision, args.cache_dir)
            loader.append(row)
            print(
                f"loader data={args.loader} workers={workers}: first batch {row['first_batch_s']:.3f} s, wait per "
                f"step {row['wait_s']} s, steps {row['step_s']} s",
                flush=True,
            )
    if args.out is not None:
        record = {
            "command": " ".join([Path(sys.executable).name, *sys.argv]),
            "commit": git_commit(ROOT) or "unknown",
            "baseline": args.baseline,
            "machine": machine(),
            "threads": torch.get_num_threads(),
            "torch": torch.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "precision": precision,
            "batch": {"B": 8, "T": 10, "view_px": 128, "tactile_px": 64, "gt_points": 2048, "patch_points": 961},
            "modes": rows,
            "loader": loader,
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, json.dumps(record, indent=2) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
