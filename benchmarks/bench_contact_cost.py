"""What the particle contact costs against the grid contact, paper-preset touches in one process (not a test).

    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/bench_contact_cost.py [--touches 6] [--first 0]
        [--eager]

Each touch (one class of ``available_classes()`` each, from ``--first``; seeded cone-policy touch; paper preset: 64x64x6
pad, n_grid 128, the paper's stop threshold in its own cells) is pressed with ``PressConfig(contact="grid")`` and
``contact="particle"``, alternating which goes first, on one thread, compiled (``EIPSimulator(compile=True)``) unless
``--eager``. The first press of each (the compile) is not timed. Prints per touch the steps and CPU seconds of both
and their ratio, then the median and total ratio particle / grid. Only ratios from one process mean something on a
loaded machine.
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

MODES = ("grid", "particle")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--touches", type=int, default=6, help="touches, one class each")
    parser.add_argument("--first", type=int, default=0, help="index of the first class")
    parser.add_argument("--eager", action="store_true", help="eager solvers (default: compiled)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    sensor = SensorConfig(resolution=(64, 64), layers=6)
    sims = {
        c: EIPSimulator(sensor, PressConfig(n_grid=128, contact=c, threshold_grid=128), compile=not args.eager)
        for c in MODES
    }
    classes = available_classes()
    jobs = []
    for i in range(args.touches):
        mesh = make_shape(classes[(args.first + i) % len(classes)], 0)
        t = sample_touches(mesh, 1, seed=i, sim=sims["grid"])
        jobs.append((classes[(args.first + i) % len(classes)], mesh, t.positions[0], t.directions[0], t.strengths[0]))
    for c in MODES:  # compile / warm up
        sims[c].press(*jobs[0][1:4], **jobs[0][4])
    print(f"torch {torch.__version__}, 1 thread, paper preset, {'eager' if args.eager else 'compiled'}")
    ratios, tot = [], dict.fromkeys(MODES, 0.0)
    for k, (name, mesh, pos, d, kw) in enumerate(jobs):
        secs, steps = {}, {}
        for c in MODES if k % 2 == 0 else MODES[::-1]:
            c0 = time.process_time()
            steps[c] = sims[c].press(mesh, pos, d, **kw).steps
            secs[c] = time.process_time() - c0
            tot[c] += secs[c]
        ratios.append(secs["particle"] / secs["grid"])
        print(
            f"{name:12s} steps grid {steps['grid']:3d} particle {steps['particle']:3d}; CPU-s grid {secs['grid']:5.2f} "
            f"particle {secs['particle']:5.2f}; ratio {ratios[-1]:5.3f}"
        )
    n = len(jobs)
    print(
        f"median particle/grid {statistics.median(ratios):.3f}, total {tot['particle'] / tot['grid']:.3f} "
        f"(grid {tot['grid'] / n:.2f}, particle {tot['particle'] / n:.2f} CPU-s per touch on this machine's load)"
    )


if __name__ == "__main__":
    main()
