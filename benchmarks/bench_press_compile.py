"""Paper-preset touches pressed eager and with ``EIPSimulator(compile=True)``, in one process (not a test).

    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/bench_press_compile.py [--touches 4] [--first 0]
        [--contact grid|particle]

Each touch (one class of ``available_classes()`` each, from ``--first``, seeded cone-policy touch, paper preset: 64x64x6
pad, n_grid 128) is pressed by the eager solver and by the fused ``torch.compile`` kernels (issue 13 step 2),
alternating which goes first, on one thread. The first compiled press (the compile) is timed apart. Prints per touch
the CPU seconds of both, their ratio and how far the readings are apart (the compiled step equals the eager one to
float32 round-off, not bit for bit); then the median and total ratio. Only ratios from one process mean something
on a loaded machine. ``--contact particle`` presses with ``PressConfig(contact="particle")`` (compiled: P2G, the grid
update, the contact passes and G2P; the search for the particles near the body eager).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--touches", type=int, default=4, help="touches, one class each")
    parser.add_argument("--first", type=int, default=0, help="index of the first class")
    parser.add_argument("--contact", choices=("grid", "particle"), default="grid", help="PressConfig.contact")
    args = parser.parse_args()
    torch.set_num_threads(1)
    sensor, press = SensorConfig(resolution=(64, 64), layers=6), PressConfig(n_grid=128, contact=args.contact)
    sims = {False: EIPSimulator(sensor, press, compile=False), True: EIPSimulator(sensor, press, compile=True)}
    classes = available_classes()
    jobs = []
    for i in range(args.touches):
        name = classes[(args.first + i) % len(classes)]
        mesh = make_shape(name, 0)
        t = sample_touches(mesh, 1, seed=i, sim=sims[False])
        jobs.append((name, mesh, t.positions[0], t.directions[0], t.strengths[0]))
    name, mesh, pos, d, kw = jobs[0]
    sims[False].press(mesh, pos, d, **kw)  # warm-up
    c0, t0 = time.process_time(), time.perf_counter()
    sims[True].press(mesh, pos, d, **kw)  # compiles (inductor's on-disk cache may shorten it)
    print(
        f"torch {torch.__version__}, 1 thread, paper preset, {args.contact} contact; first compiled press (compile): "
        f"{time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} CPU-s"
    )
    ratios, tot = [], {False: 0.0, True: 0.0}
    for k, (name, mesh, pos, d, kw) in enumerate(jobs):
        secs, reads = {}, {}
        for c in (False, True) if k % 2 == 0 else (True, False):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                c0 = time.process_time()
                reads[c] = sims[c].press(mesh, pos, d, **kw)
                secs[c] = time.process_time() - c0
            tot[c] += secs[c]
        ratios.append(secs[False] / secs[True])
        e, n = reads[False], reads[True]
        di = (e.image - n.image).abs().max().item()
        df = (e.force - n.force).norm().item() / max(e.force.norm().item(), 1e-30)
        print(
            f"{name:12s} steps {e.steps:3d}/{n.steps:3d} eager {secs[False]:5.2f} CPU-s compiled {secs[True]:5.2f} "
            f"CPU-s ratio {ratios[-1]:5.3f}; max|d image| {di:.2g} (image max {e.image.abs().max().item():.3g}), "
            f"|d force|/|force| {df:.2g}, d depth {abs(float(e.depth) - float(n.depth)):.2g}"
        )
    print(
        f"median eager/compiled {statistics.median(ratios):.3f}, total {tot[False] / tot[True]:.3f} "
        f"({tot[False] / len(jobs):.2f} -> {tot[True] / len(jobs):.2f} CPU-s per touch on this machine's load)"
    )


if __name__ == "__main__":
    main()
