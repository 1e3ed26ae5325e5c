"""A batch's touch set-up in threads against spawned processes (``EIPSimulator(setup_processes=N)``), wall time.

    python -m benchmarks.speed.bench_setup_pool --workers 2 --batch 20 --repeats 3

The paper scene of ``bench_gpu.py`` (the authors' 61x61x10 pad, n_grid 128, one object's paper sweep tiled to the
batch), placed with ``EIPSimulator.place_batch`` on the CPU: ``--workers`` threads, then ``--workers`` processes (the
pool started and warmed before the timings), alternating which goes first each round. Wall seconds per batch (the
processes' CPU time is not the calling process's), the threads / processes ratio per round and its median, and
whether every placement is bit-identical. On a GPU host, ``bench_gpu.py --setup-processes 0,16`` times whole presses.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import torch

from benchmarks._common import paper_scene, same, tile
from tvrecon.sim import EIPSimulator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2, help="threads, and processes, placing the touches")
    parser.add_argument("--batch", type=int, default=20, help="touches per place_batch call")
    parser.add_argument("--repeats", type=int, default=3, help="rounds (each times both)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)
    sensor, press, mesh, pos, dirs, strength = paper_scene("cpu")
    pos, dirs = tile(pos, args.batch), tile(dirs, args.batch)
    threads = EIPSimulator(sensor, press, setup_threads=args.workers)
    procs = EIPSimulator(sensor, press, setup_processes=args.workers)
    t0 = time.perf_counter()
    procs.place_batch(mesh, pos[: args.workers * 2], dirs[: args.workers * 2], **strength)  # start the pool
    print(f"paper scene, batch {args.batch}, {args.workers} workers; pool start {time.perf_counter() - t0:.2f} s")
    ratios, identical = [], True
    for r in range(args.repeats):
        order = [("threads", threads), ("processes", procs)]
        if r % 2:
            order.reverse()
        secs, placed = {}, {}
        for name, sim in order:
            t0 = time.perf_counter()
            placed[name] = sim.place_batch(mesh, pos, dirs, **strength)
            secs[name] = time.perf_counter() - t0
        identical &= all(same(a, b) for a, b in zip(placed["threads"], placed["processes"], strict=True))
        ratios.append(secs["threads"] / secs["processes"])
        print(
            f"  round {r}: threads {secs['threads']:.2f} s ({secs['threads'] / args.batch * 1e3:.0f} ms a touch), "
            f"processes {secs['processes']:.2f} s ({secs['processes'] / args.batch * 1e3:.0f} ms), "
            f"ratio {ratios[-1]:.2f}"
        )
    procs.close()
    print(f"median threads / processes: {statistics.median(ratios):.2f}; placements bit-identical: {identical}")


if __name__ == "__main__":
    main()
