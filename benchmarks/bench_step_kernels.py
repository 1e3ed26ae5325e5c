"""Where a compiled press step's time goes, kernel by kernel (not a test): one warm ``press_batch`` of the paper scene
(``bench_gpu.py``'s: the authors' 61x61x10 pad, n_grid 128, one object's paper sweep) with every compiled kernel
call (``CompiledKernels``) and the fused C++ loops (``compiled.scatter.fused_p2g``, ``compiled.gather.fused_g2p``,
``compiled.contact.fused_contact``, ``compiled.polar.fused_polar``) timed by wall clock around the call.

    OMP_NUM_THREADS=1 python benchmarks/bench_step_kernels.py [--batch 10] [--device cpu] [--keep-heap]

Prints the call's wall and CPU time, its steps, and per kernel the ms per call, the calls and the share of the
call (``--keep-heap``: :func:`tvrecon.utils.freed_memory.keep_freed_memory` first, as ``generate`` does); ``fused_step``
is the whole compiled step (the kernels plus its eager glue), the rest of the call the press
loop, set-up and readings. On CUDA each call is synchronized before and after (the times then include the launch
and the wait). Only shares and ratios from one run mean something on a loaded machine.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_gpu import _tile, paper_scene  # noqa: E402

import tvrecon.sim.mpm.compiled.backend as backend  # noqa: E402
import tvrecon.sim.mpm.compiled.step as compiled_step  # noqa: E402
import tvrecon.sim.mpm.free_flight as free_flight  # noqa: E402
import tvrecon.sim.mpm.particle_contact as particle_contact  # noqa: E402
import tvrecon.sim.mpm.solver as solver  # noqa: E402
from tvrecon.sim import EIPSimulator  # noqa: E402
from tvrecon.utils.freed_memory import keep_freed_memory  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, default=10, help="touches in the press_batch call")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--keep-heap", action="store_true", help="keep freed memory in the process, as generate does")
    args = parser.parse_args()
    if args.keep_heap and not keep_freed_memory():
        print("keep_freed_memory: not glibc here, the heap is as by default")
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")  # thin-part contact warnings of the paper scene: not what is measured here
    device = torch.device(args.device)
    seconds: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    def timed(name: str, fn: Callable) -> Callable:
        def run(*a, **k):
            sync()
            t0 = time.perf_counter()
            out = fn(*a, **k)
            sync()
            seconds[name] += time.perf_counter() - t0
            calls[name] += 1
            return out

        return run

    kernel_call = backend.CompiledKernels.__call__
    backend.CompiledKernels.__call__ = lambda self, name, *a: timed(name, kernel_call)(self, name, *a)
    compiled_step.fused_p2g = timed("p2g (C++)", compiled_step.fused_p2g)
    compiled_step.fused_g2p = timed("g2p (C++)", compiled_step.fused_g2p)
    particle_contact.fused_contact = timed("contact (C++)", particle_contact.fused_contact)
    compiled_step.fused_polar = timed("polar (C++)", compiled_step.fused_polar)
    free_flight.FreeFlight.step = timed("free flight", free_flight.FreeFlight.step)  # tried every step until contact
    solver.fused_step = timed("fused_step", solver.fused_step)

    sensor, press, mesh, pos, dirs, strength = paper_scene(args.device)
    sim = EIPSimulator(sensor, press, device=device, compile=True)
    sim.press_batch(mesh, _tile(pos, args.batch), _tile(dirs, args.batch), **strength)  # compile, warm caches
    seconds.clear()
    calls.clear()
    sync()
    t0, c0 = time.perf_counter(), time.process_time()
    readings = sim.press_batch(mesh, _tile(pos, args.batch), _tile(dirs, args.batch), **strength)
    sync()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    steps = max(int(r.steps) for r in readings)
    print(f"torch {torch.__version__}, {device}, {torch.get_num_threads()} thread(s), keep heap {args.keep_heap}")
    print(f"batch {args.batch}: {wall:.2f} s wall, {cpu:.2f} CPU-s, {steps} steps, {1000 * wall / steps:.1f} ms a step")
    print(f"  {'kernel':14s} {'ms/call':>8s} {'calls':>6s} {'share':>6s}")
    for name, s in sorted(seconds.items(), key=lambda kv: -kv[1]):
        print(f"  {name:14s} {1000 * s / calls[name]:8.2f} {calls[name]:6d} {100 * s / wall:5.1f}%")


if __name__ == "__main__":
    main()
