"""Paper-preset touches one per solver call vs batched per object as data generation runs them (not a test).

    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/bench_press_batch.py [--objects 2]
        [--touches 10] [--first 0] [--compile]

For each object (one class of ``available_classes()`` each, from ``--first``) ``--touches`` seeded cone-policy touches
are pressed with the paper preset (64x64x6 pad, n_grid 128) twice, alternating which goes first, on one thread:
one ``press`` per touch, and ``simulate_touches`` (one ``press_batch`` per press strength, as
``tvrecon.data.dataset_base`` does for an item). Prints the CPU seconds per touch of both, their ratio and how far
the readings are apart (batched equals single to float round-off: a block's contact force is summed per scene, but
the shared loop stops each touch at its own step). Only ratios from one process mean something on a loaded machine.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches, simulate_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--objects", type=int, default=2, help="objects, one class each")
    parser.add_argument("--touches", type=int, default=10, help="touches per object (an item's M)")
    parser.add_argument("--first", type=int, default=0, help="index of the first class")
    parser.add_argument("--compile", action="store_true", help="EIPSimulator(compile=True)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sim = EIPSimulator(SensorConfig(resolution=(64, 64), layers=6), PressConfig(n_grid=128), compile=args.compile)
    classes = available_classes()
    jobs = []
    for i in range(args.objects):
        name = classes[(args.first + i) % len(classes)]
        mesh = make_shape(name, 0)
        jobs.append((name, mesh, sample_touches(mesh, args.touches, seed=i, sim=sim)))
    warnings.simplefilter("ignore")
    t0 = jobs[0][2]
    sim.press(jobs[0][1], t0.positions[0], t0.directions[0], **t0.strengths[0])  # warm-up (and compile)
    mode = "compiled" if args.compile else "eager"
    print(f"torch {torch.__version__}, 1 thread, {mode}, paper preset; {args.objects} objects x {args.touches} touches")
    tot = {"single": 0.0, "batched": 0.0}
    n = 0
    for k, (name, mesh, t) in enumerate(jobs):
        secs, reads = {}, {}
        for which in ("single", "batched") if k % 2 == 0 else ("batched", "single"):
            c0 = time.process_time()
            if which == "single":
                reads[which] = [
                    sim.press(mesh, p, d, **s) for p, d, s in zip(t.positions, t.directions, t.strengths, strict=True)
                ]
            else:
                reads[which] = simulate_touches(sim, mesh, t, batch_size=args.touches)
            secs[which] = time.process_time() - c0
            tot[which] += secs[which]
        n += len(t.positions)
        di = max((a.image - b.image).abs().max().item() for a, b in zip(reads["single"], reads["batched"], strict=True))
        steps = sum(r.steps for r in reads["single"])
        same_steps = all(a.steps == b.steps for a, b in zip(reads["single"], reads["batched"], strict=True))
        m = len(t.positions)
        print(
            f"{name:12s} {steps:4d} steps single {secs['single'] / m:5.2f} batched {secs['batched'] / m:5.2f} "
            f"CPU-s/touch, single/batched {secs['single'] / secs['batched']:5.3f}; same steps {same_steps}, "
            f"max|d image| {di:.2g}"
        )
    print(
        f"total single/batched {tot['single'] / tot['batched']:.3f} "
        f"({tot['single'] / n:.2f} -> {tot['batched'] / n:.2f} CPU-s per touch on this machine's load)"
    )


if __name__ == "__main__":
    main()
