"""The compiled step's C++ P2G scatter and G2P gather of an earlier commit against the working tree's, on the same
inputs, in one process (not a test).

    OMP_NUM_THREADS=1 python -m benchmarks.probes.bench_cpp_loops --old REV [--scene paper|bench] [--batch 10]
        [--rounds 15]

One warm ``press_batch`` of ``bench_gpu.py``'s scene (``paper``: the authors' 61x61x10 pad, n_grid 128, one object's
paper sweep, ``--batch`` touches; ``bench``: the 48x48x12 pad on a sphere) is pressed with ``compile=True`` on one
thread, and the inputs of its ``--step``-th fused P2G and G2P calls are kept. The ``SOURCE`` of
``compiled/scatter.py`` and ``compiled/gather.py`` at ``REV`` (``git show``) and in the working tree are built with
inductor's C++ toolchain (as ``CppLoop`` does) and called on those inputs in alternating rounds. Prints per loop the
median ms of each, the old/new ratio and the largest difference of the outputs relative to their largest magnitude
(the loops sum the same terms in other orders: float32 round-off). Only ratios from one run mean something on a
loaded machine.
"""

from __future__ import annotations

import argparse
import ctypes
import statistics
import subprocess
import time
import warnings
from collections.abc import Callable

import torch

import tvrecon.sim.mpm.compiled.gather as gather
import tvrecon.sim.mpm.compiled.scatter as scatter
import tvrecon.sim.mpm.compiled.step as compiled_step
from benchmarks._common import ROOT, SCENES, tile
from tvrecon.sim import EIPSimulator
from tvrecon.sim.mpm.compiled.cpp_loop import ptr


def old_source(rev: str, module: str) -> str:
    """``SOURCE`` of ``tvrecon/sim/mpm/compiled/<module>.py`` at commit ``rev`` (the module's text, executed alone)."""
    text = subprocess.run(
        ["git", "show", f"{rev}:tvrecon/sim/mpm/compiled/{module}.py"], cwd=ROOT, check=True, capture_output=True
    ).stdout.decode()
    start = text.index('SOURCE = r"""')
    end = text.index('"""', start + len('SOURCE = r"""'))
    return text[start + len('SOURCE = r"""') : end]


def capture(scene: str, batch: int, step: int) -> dict[str, list]:
    """The arguments of the ``step``-th fused P2G and G2P call of a warm press of ``scene`` (cloned)."""
    seen: dict[str, list] = {}
    count = {"p2g": 0, "g2p": 0}

    def keep(name: str, fn: Callable) -> Callable:
        def run(*a):
            count[name] += 1
            if count[name] == step:
                seen[name] = [t.clone() if isinstance(t, torch.Tensor) else t for t in a]
            return fn(*a)

        return run

    sensor, press, mesh, pos, dirs, strength = SCENES[scene]("cpu")
    sim = EIPSimulator(sensor, press, device=torch.device("cpu"), compile=True)
    sim.press_batch(mesh, tile(pos, batch), tile(dirs, batch), **strength)  # compile, warm caches
    p2g, g2p = compiled_step.fused_p2g, compiled_step.fused_g2p
    compiled_step.fused_p2g, compiled_step.fused_g2p = keep("p2g", p2g), keep("g2p", g2p)
    try:
        sim.press_batch(mesh, tile(pos, batch), tile(dirs, batch), **strength)
    finally:
        compiled_step.fused_p2g, compiled_step.fused_g2p = p2g, g2p
    if len(seen) != 2:
        raise SystemExit(f"the press made fewer than {step} fused steps ({count}); pass a smaller --step")
    return seen


def _build(source: str, name: str):
    from torch._inductor.codecache import CppCodeCache

    fn = getattr(CppCodeCache.load(source), name)
    fn.restype = ctypes.c_int64
    return fn


def p2g_call(source: str, args: list) -> Callable[[], list[torch.Tensor]]:
    """The loop of ``source`` on ``fused_p2g``'s arguments; an older source also takes a (13, P) buffer ``q``."""
    Ft, Rt, Ct, vt, fx, m, vol, lin, n_nodes, S0, S1, mu, lam, dt, dx, inv_dx = args
    P = lin.shape[0]
    fn, with_q = _build(source, "p2g_grid"), "float* q, float* grid" in source
    q, grid = torch.empty(13, P), torch.zeros(n_nodes, 4)
    head = [ptr(t) for t in (Ft, Rt, Ct, vt, fx, m, vol, lin)] + [ctypes.c_int64(k) for k in (P, S0, S1, n_nodes)]
    tail = [ptr(q)] if with_q else []
    call = [*head, *(ctypes.c_float(k) for k in (mu, lam, dt, dx, inv_dx)), *tail, ptr(grid)]

    def run() -> list[torch.Tensor]:
        grid.zero_()
        if fn(*call):
            raise RuntimeError("a stencil left the block")
        return [grid]

    run.buffers = (q, grid)  # the call holds raw pointers to them: they live as long as the call
    return run


def g2p_call(source: str, args: list) -> Callable[[], list[torch.Tensor]]:
    """The loop of ``source`` on ``fused_g2p``'s arguments."""
    gv, lin, fx, xt, Ft, alpha, hvt, S0, S1, dt, inv_dx = args
    P = lin.shape[0]
    fn = _build(source, "g2p_grid")
    out = [torch.empty(k, P) for k in (3, 3, 9, 9)]
    stride = 0 if hvt is None or hvt.shape[1] == 1 else 1
    ints = [ctypes.c_int64(k) for k in (stride, P, S0, S1, gv.shape[0])]
    call = [ptr(gv), ptr(lin), ptr(fx), ptr(xt), ptr(Ft), ptr(alpha), ptr(hvt), *ints]
    call += [ctypes.c_float(dt), ctypes.c_float(inv_dx), *map(ptr, out)]

    def run() -> list[torch.Tensor]:
        if fn(*call):
            raise RuntimeError("a stencil left the block")
        return out

    return run


def compare(name: str, old: Callable, new: Callable, rounds: int) -> None:
    want = [t.clone() for t in old()]
    got = new()
    diff = max(float((a - b).abs().max() / b.abs().max().clamp_min(1e-30)) for a, b in zip(got, want, strict=True))
    times: dict[str, list[float]] = {"old": [], "new": []}
    for r in range(rounds):
        for label, fn in (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old)):
            t0 = time.perf_counter()
            fn()
            times[label].append(time.perf_counter() - t0)
    o, n = (1000 * statistics.median(times[k]) for k in ("old", "new"))
    print(f"  {name}: old {o:6.2f} ms, new {n:6.2f} ms, old/new {o / n:4.2f}x, largest difference {diff:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", required=True, help="the commit whose loops are the reference")
    parser.add_argument("--scene", choices=sorted(SCENES), default="paper")
    parser.add_argument("--batch", type=int, default=10, help="touches in the press_batch call")
    parser.add_argument("--step", type=int, default=60, help="which fused step's inputs are kept")
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")  # thin-part contact warnings of the paper scene: not what is measured here
    seen = capture(args.scene, args.batch, args.step)
    P = seen["g2p"][1].shape[0]
    print(f"torch {torch.__version__}, {args.scene} scene, batch {args.batch}: {P} particles, step {args.step}")
    print(f"old: {args.old}; new: the working tree")
    compare("P2G", p2g_call(old_source(args.old, "scatter"), seen["p2g"]), p2g_call(scatter.SOURCE, seen["p2g"]),
            args.rounds)  # fmt: skip
    compare("G2P", g2p_call(old_source(args.old, "gather"), seen["g2p"]), g2p_call(gather.SOURCE, seen["g2p"]),
            args.rounds)  # fmt: skip


if __name__ == "__main__":
    main()
