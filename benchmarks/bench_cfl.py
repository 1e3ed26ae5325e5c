"""The press's time step: how much a paper touch's reading moves, and what it costs, at multiples of the CFL step.

    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/bench_cfl.py [--preset cls_paper]
        [--objects 6] [--factors 0.5 1 1.5 2] [--out benchmarks/results/.../cfl.json]

Each object (class ``first + stride * i`` of ``available_classes()``, instance 0) gets one sweep of the preset's touch
policy (10 paper touches through its centre), pressed in one batch at ``dt = factor * cfl_dt`` for every factor
(``PressConfig.dt`` per call; the hand's speed is a fraction of the wave speed, so a larger step is the same press in
fewer, longer steps, and the depth stop is the same travel). The smallest factor is the reference. Prints per factor:
CPU seconds per touch, solver steps, batches that diverged, and against the reference the image difference (max and
mean over the taxels the reference pushed > 0.1 cells, in grid cells), the normal force's relative difference, and
contact flags that disagree. Not a test; the ratios of one process are what compare.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tvrecon.data.presets import compose_preset  # noqa: E402
from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig  # noqa: E402
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="cls_paper", help="data preset: its pad, press and touch policy")
    parser.add_argument("--objects", type=int, default=6)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--stride", type=int, default=6)
    parser.add_argument("--factors", type=float, nargs="+", default=[0.5, 1.0, 1.5, 2.0])
    parser.add_argument("--out", type=Path, default=None, help="write the per-factor summary as JSON")
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = compose_preset(args.preset, ["cache_dir=null"])
    sensor_kw = OmegaConf.to_container(cfg.sensor)
    sensor_kw["resolution"] = tuple(sensor_kw["resolution"])
    press_kw = {k: v for k, v in OmegaConf.to_container(cfg.press).items() if k != "compile"}
    sim = EIPSimulator(SensorConfig(**sensor_kw), PressConfig(**press_kw), compile=True)
    policy = instantiate(cfg.touch)
    dt0 = sim._mpm_config(sim.sensor, sim.cfg).dt
    factors = sorted(args.factors)
    classes = available_classes()
    names = [classes[(args.first + args.stride * i) % len(classes)] for i in range(args.objects)]
    # warm-up: the compiled kernels, so the first factor does not pay the compile
    warm = make_shape(names[0], 0)
    t = sample_touches(warm, 2, seed=0, policy=policy, sim=sim)
    sim.press_batch(warm, t.positions, t.directions, **t.strengths[0])
    rows: dict[float, dict[str, list]] = {
        f: {"cpu": [], "steps": [], "diverged": [], "max": [], "mean": [], "force": [], "contact": []} for f in factors
    }
    for i, name in enumerate(names):
        mesh = make_shape(name, 0)
        t = sample_touches(mesh, 10, seed=100 + i, policy=policy, sim=sim)
        ref = None
        for f in factors:
            t0 = time.process_time()
            try:
                out = sim.press_batch(mesh, t.positions, t.directions, dt=f * dt0, **t.strengths[0])
            except FloatingPointError:
                rows[f]["diverged"].append(name)
                print(f"{name:12s} x{f:<4g} diverged", flush=True)
                continue
            cpu = (time.process_time() - t0) / len(out)
            r = rows[f]
            r["cpu"].append(cpu)
            r["steps"].append(max(o.steps for o in out))
            if ref is None:
                ref = out
            for a, b in zip(out, ref, strict=True):
                pushed = b.image[2].abs() > 0.1
                diff = (a.image - b.image).abs()
                r["max"].append(float(diff.max()))
                r["mean"].append(float(diff[:, pushed].mean()) if bool(pushed.any()) else 0.0)
                fa, fb = float(a.force.norm()), float(b.force.norm())
                r["force"].append(abs(fa - fb) / max(fb, 1e-12))
                r["contact"].append(bool(a.contact) != bool(b.contact))
            print(
                f"{name:12s} x{f:<4g} {cpu:6.3f} CPU-s/touch, {r['steps'][-1]} steps, image max diff "
                f"{max(r['max'][-len(out) :]):.3f} cells",
                flush=True,
            )
    summary = {}
    base_cpu = statistics.median(rows[1.0]["cpu"]) if rows.get(1.0) and rows[1.0]["cpu"] else None
    print(f"\n{args.preset}: {len(names)} objects x 10 touches, cfl_dt = {dt0:.4g} s; reference x{factors[0]:g}")
    print("factor  CPU-s/touch  vs x1  steps  diverged  image max / mean diff (cells)  force rel diff  contact flips")
    for f in factors:
        r = rows[f]
        if not r["cpu"]:
            print(f"x{f:<5g} every batch diverged")
            continue
        s = {
            "cpu_per_touch": statistics.median(r["cpu"]),
            "steps": statistics.median(r["steps"]),
            "diverged": r["diverged"],
            "image_max_diff": max(r["max"]),
            "image_mean_diff": statistics.mean(r["mean"]),
            "force_rel_diff_median": statistics.median(r["force"]),
            "force_rel_diff_max": max(r["force"]),
            "contact_flips": sum(r["contact"]),
        }
        summary[f] = s
        speed = f"{base_cpu / s['cpu_per_touch']:5.2f}x" if base_cpu else "  -  "
        print(
            f"x{f:<5g} {s['cpu_per_touch']:11.3f}  {speed}  {s['steps']:5.0f}  {len(s['diverged']):8d}  "
            f"{s['image_max_diff']:13.3f} / {s['image_mean_diff']:.4f}  {s['force_rel_diff_median']:9.4f} "
            f"(max {s['force_rel_diff_max']:.3f})  {s['contact_flips']:5d}"
        )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps({"preset": args.preset, "objects": names, "cfl_dt": dt0, "factors": summary}, indent=1) + "\n"
        )


if __name__ == "__main__":
    main()
