"""Press throughput against batch size on one device: touches/s, particle-steps/s, peak memory, ops and syncs per step.

    python benchmarks/bench_gpu.py                                   # CPU: batches 1,2,4,8, eager and compiled
    python benchmarks/bench_gpu.py --device cuda --out bench_gpu.json   # a GPU: batches 1 .. 1024 until memory runs out
    python benchmarks/bench_gpu.py --device cuda --scenes bench --modes eager --batches 64 --profile 64  # + top ops

Two scenes, both through the public press API (``EIPSimulator.press_batch``, one solver loop for B touches):

- ``paper``: the authors' geometry of ``preset=paper`` (61x61x10 pad, n_grid 128, the object at 0.16 of the domain)
  with the paper's touches (``touch/paper_sweep``: through the centre, a side-to-top sweep, 12% of the object deep).
  A batch of B touches is the first object's sweep repeated (same mesh, same stop rule, one loop).
- ``bench``: the solver bench scene of ``bench_sim.py`` as a press: a 48x48x12 pad on n_grid 128 pressed straight
  down on a sphere of radius 0.1 domain units.

Modes: ``eager`` and ``compiled`` (``EIPSimulator(compile=True)``: the fused ``torch.compile`` kernels). The first
call of each (scene, mode, batch) is a warm-up (compile included) and is reported apart; then ``--repeats`` timed
calls. Time is wall time with ``torch.cuda.synchronize`` on CUDA and process CPU time on CPU (robust on a loaded
machine; divide by ``--threads`` for wall time on idle cores). particle-steps/s counts each touch's pad particles for
the steps that touch ran (a finished touch leaves the loop). Peak memory: ``torch.cuda.max_memory_allocated`` on
CUDA, the process's max RSS on CPU (monotonic over the run).

``loop p-s/s``: particle-steps per second of the call less its set-up (the solver loop's own rate).
``setup s``: the host set-up of the batch alone (``EIPSimulator.place_batch``: each touch's frame, touch point and mesh
collider, in ``setup_threads`` threads; ``--setup-threads 1,auto`` compares them; ``--setup-processes 0,16`` compares
threads with 16 spawned set-up processes, ``EIPSimulator(setup_processes=16)``, GPU only: the CPU clock here is the
process's own), timed once after the calls; it is part of ``s/call``. ``thr`` is the set-up's threads, or ``pN``.

Ops and syncs per step (``--count-batch``, default 4; ``--count-modes eager,compiled``): the aten ops dispatched during
one ``press_batch`` call, counted with a ``TorchDispatchMode``, less those of the same call stopped after one step, per
further step; also without the ops that only make views (no kernel on a GPU). The dispatch mode runs compiled code
eagerly, so the compiled press is counted from a profiler trace instead (CPU only: one op per fused inductor kernel
call plus the aten ops left outside the kernels; compiled afresh with a record per kernel, minutes on one thread).
A host sync is an op whose result the host must wait for: ``_local_scalar_dense`` (``.item()``, ``bool(tensor)``),
``nonzero``, ``masked_select``, ``unique*``, ``repeat_interleave`` with tensor repeats and boolean-mask indexing.
On a GPU each op is a kernel launch and each sync a stall. CUDA graphs are not measured: the press loop checks its
stop rule on the host every step, so the step cannot be captured yet.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import resource
import sys
import time
import warnings
from pathlib import Path

import torch
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hydra.utils import instantiate  # noqa: E402

from tvrecon.data.presets import compose_preset  # noqa: E402
from tvrecon.data.touches.policies import sample_touches  # noqa: E402
from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig  # noqa: E402
from tvrecon.sim.mpm.solver import MLSMPM  # noqa: E402
from tvrecon.sim.press.loop import PressLoop  # noqa: E402
from tvrecon.utils.op_counter import OpCounter, ProfiledCounter, kernel_profile, per_step  # noqa: E402


def paper_scene(device: str) -> tuple[SensorConfig, PressConfig, trimesh.Trimesh, torch.Tensor, torch.Tensor, dict]:
    """The authors' pad and grid with one object's paper sweep (``preset=paper``, first training object)."""
    cfg = compose_preset("paper", ["cache_dir=null"])
    ds = instantiate(cfg, _convert_="all").make_dataset("train")
    mesh = ds.mesh(0)
    sim = EIPSimulator(ds.sensor, ds.press, device=device)
    t = sample_touches(mesh, 10, seed=0, policy=ds.touch, sim=sim)
    if any(s != t.strengths[0] for s in t.strengths):
        raise RuntimeError("the paper sweep's touches of one object should share one stop rule")
    return ds.sensor, ds.press, mesh, t.positions, t.directions, dict(t.strengths[0])


def bench_scene(device: str) -> tuple[SensorConfig, PressConfig, trimesh.Trimesh, torch.Tensor, torch.Tensor, dict]:
    """``bench_sim.py``'s scene as a press: 48x48x12 pad, n_grid 128 on the unit domain, a sphere of radius 0.1."""
    sensor = SensorConfig(resolution=(48, 48), layers=12)
    press = PressConfig(n_grid=128, domain_size=1.0)
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1]])
    dirs = torch.tensor([[0.0, 0.0, -1.0]])
    return sensor, press, mesh, pos, dirs, {}


SCENES = {"paper": paper_scene, "bench": bench_scene}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _clock(device: torch.device) -> float:
    return time.perf_counter() if device.type == "cuda" else time.process_time()


def _peak_mib(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10  # KiB on Linux


def _tile(x: torch.Tensor, b: int) -> torch.Tensor:
    """(T, 3) -> (b, 3): the touches repeated until the batch is full."""
    return x.repeat(math.ceil(b / x.shape[0]), 1)[:b]


def run_one(sim: EIPSimulator, mesh, pos, dirs, strength: dict, b: int, device: torch.device) -> tuple[float, list]:
    """Seconds (wall on CUDA, CPU elsewhere) and readings of one ``press_batch`` of ``b`` touches."""
    _sync(device)
    t0 = _clock(device)
    readings = sim.press_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength)
    _sync(device)
    return _clock(device) - t0, readings


def count_ops(
    sensor,
    press,
    mesh,
    pos,
    dirs,
    strength: dict,
    b: int,
    device: torch.device,
    chunks: bool = True,
    compiled: bool = False,
) -> dict:
    """Aten ops and host syncs per loop step of one ``press_batch`` of ``b`` touches
    (:func:`tvrecon.utils.op_counter.per_step`: the set-up and read-out, paid once per call, cancel).

    ``compiled=True`` counts the compiled press (``EIPSimulator(compile=True)``) from a profiler trace
    (:class:`~tvrecon.utils.op_counter.ProfiledCounter`: each fused inductor kernel call is one op, as is each aten op
    left in eager code or called by a compiled graph's wrapper), compiled on the CPU with a profiler record per
    kernel (:func:`~tvrecon.utils.op_counter.kernel_profile`, a compile of its own: minutes on one thread).

    ``chunks=False`` counts the GPU's layout on the CPU: the stencil passes in one launch instead of cache-sized
    particle chunks (``MLSMPM.chunk_size``; off on a GPU anyway) and the polar decomposition's convergence test left
    to the loop's read (``MLSMPM.deferred_polar``), the contact's kept candidate list (``MLSMPM.contact_skin``), the
    node-major P2G scatter (``MLSMPM.node_major_p2g``) and one host read per 4 steps (``PressLoop.read_every``), as on
    CUDA by default."""
    sim = EIPSimulator(sensor, press, device=device, compile=compiled)

    def run(max_steps: int | None) -> int:
        limit = {} if max_steps is None else {"max_steps": max_steps}
        readings = sim.press_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength, **limit)
        return max(int(r.steps) for r in readings)

    saved = MLSMPM.chunk_size, MLSMPM.deferred_polar, MLSMPM.contact_skin, MLSMPM.node_major_p2g, PressLoop.read_every
    if not chunks:
        MLSMPM.chunk_size, MLSMPM.deferred_polar, MLSMPM.contact_skin, MLSMPM.node_major_p2g = 0, True, 0.5, True
        PressLoop.read_every = 4
    try:
        layout = "cpu chunks" if chunks and device.type == "cpu" else "one pass, deferred polar, list, 4 steps a read"
        with kernel_profile() if compiled else contextlib.nullcontext():
            # warm caches (placement, SDF) like a real run; compiled: every graph, and its recompiles, compiled here
            sim.press_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength)
            counts = per_step(run, ProfiledCounter if compiled else OpCounter)
        return {"batch": b, "layout": layout, "mode": "compiled" if compiled else "eager", **counts}
    finally:
        MLSMPM.chunk_size, MLSMPM.deferred_polar, MLSMPM.contact_skin, MLSMPM.node_major_p2g = saved[:4]
        PressLoop.read_every = saved[4]


def _threads(value: str) -> int | None:
    return None if value == "auto" else int(value)


def _write(path: Path | None, results: dict) -> None:
    """Every figure so far to ``path`` (temp file, then rename): a run cut off by a time limit keeps its rows."""
    if path is None:
        return
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(results, indent=1))
    tmp.replace(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--scenes", default="paper,bench", help="comma-separated: " + ", ".join(SCENES))
    parser.add_argument("--modes", default="eager,compiled", help="comma-separated: eager, compiled")
    parser.add_argument("--batches", default=None, help="comma-separated batch sizes (default 1..8 CPU, 1..1024 CUDA)")
    parser.add_argument("--repeats", type=int, default=1, help="timed calls per (scene, mode, batch)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--count-batch", type=int, default=4, help="batch of the op/sync count (0: skip)")
    parser.add_argument(
        "--count-modes",
        default="eager",
        help="comma-separated modes of the op/sync count: eager (dispatch mode), compiled (profiler trace; CPU only)",
    )
    parser.add_argument("--out", type=Path, default=None, help="write every figure to this JSON file")
    parser.add_argument(
        "--setup-threads",
        default="auto",
        help="comma-separated EIPSimulator(setup_threads=...) values to compare, 'auto' = the default policy",
    )
    parser.add_argument(
        "--setup-processes",
        default="0",
        help="comma-separated EIPSimulator(setup_processes=...) values to compare (0: threads; GPU only)",
    )
    parser.add_argument(
        "--profile", type=int, default=0, help="after the timings, profile one call of this batch (torch.profiler)"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")  # thin-part contact warnings of the paper scene: not what is measured here
    device = torch.device(args.device)
    on_cuda = device.type == "cuda"
    batches = [int(b) for b in args.batches.split(",")] if args.batches else [2**k for k in range(11 if on_cuda else 4)]
    procs = [int(n) for n in args.setup_processes.split(",")]
    if any(procs) and not on_cuda:
        parser.error(
            "--setup-processes is timed in wall seconds on a GPU; on the CPU (process CPU time, which does "
            "not see the workers) compare set-ups with benchmarks/bench_setup_pool.py"
        )
    name = torch.cuda.get_device_name(device) if on_cuda else f"CPU, {args.threads} thread(s)"
    print(f"torch {torch.__version__}, {name}; time = {'wall' if on_cuda else 'process CPU'} seconds")
    results: dict = {"device": name, "torch": torch.__version__, "runs": [], "counts": []}
    for scene in args.scenes.split(","):
        sensor, press, mesh, pos, dirs, strength = SCENES[scene](str(device))
        particles = sensor.resolution[0] * sensor.resolution[1] * sensor.layers
        print(
            f"\n[{scene}] pad {sensor.resolution[0]}x{sensor.resolution[1]}x{sensor.layers} = {particles} particles, "
            f"n_grid {press.n_grid}, stop {strength or 'eq. 12 threshold'}"
        )
        if args.count_batch:
            layouts = (True, False) if device.type == "cpu" else (True,)
            for mode in args.count_modes.split(","):
                if mode == "compiled" and device.type != "cpu":
                    print("  compiled counts are read from inductor's CPU kernel records: skipped on", device)
                    continue
                for chunks in layouts:
                    c = count_ops(
                        sensor, press, mesh, pos, dirs, strength, args.count_batch, device, chunks, mode == "compiled"
                    )
                    results["counts"].append({"scene": scene, **c})
                    _write(args.out, results)
                    print(
                        f"  {mode}, batch {c['batch']}, {c['layout']}: {c['ops_per_step']:.0f} aten ops "
                        f"({c['launch_ops_per_step']:.0f} not views) and {c['syncs_per_step']:.1f} host syncs per step "
                        f"({c['steps']} steps; {c['ops_outside_steps']:.0f} ops per call outside the steps); "
                        f"syncs {c['syncs_by_op']}; most ops {c['top_ops']}"
                    )
        print(
            f"  {'mode':9s} {'batch':>5s} {'first s':>8s} {'s/call':>8s} {'touches/s':>10s} {'p-steps/s':>10s} "
            f"{'steps':>6s} {'peak MiB':>9s} {'setup s':>8s} {'thr':>4s} {'loop p-s/s':>10s}"
        )
        combos = [(m, t, n) for m in args.modes.split(",") for t in args.setup_threads.split(",") for n in procs]
        for mode, threads, nproc in combos:
            sim = EIPSimulator(
                sensor,
                press,
                device=device,
                compile=mode == "compiled",
                setup_threads=_threads(threads),
                setup_processes=nproc,
            )
            for b in batches:
                if on_cuda:
                    torch.cuda.reset_peak_memory_stats(device)
                try:
                    first, _ = run_one(sim, mesh, pos, dirs, strength, b, device)
                    secs, readings = [], None
                    for _ in range(args.repeats):
                        s, readings = run_one(sim, mesh, pos, dirs, strength, b, device)
                        secs.append(s)
                except torch.cuda.OutOfMemoryError:
                    print(f"  {mode:9s} {b:5d} out of memory: larger batches skipped")
                    torch.cuda.empty_cache()
                    break
                sec = min(secs)
                _sync(device)
                t0 = _clock(device)
                sim.place_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength)  # the host set-up alone
                setup = _clock(device) - t0
                steps = [int(r.steps) for r in readings]
                row = {
                    "scene": scene,
                    "mode": mode,
                    "setup_threads": sim._setup_workers(b),
                    "setup_processes": nproc,
                    "setup_s": setup,
                    "batch": b,
                    "first_s": first,
                    "s_per_call": sec,
                    "touches_per_s": b / sec,
                    "particle_steps_per_s": particles * sum(steps) / sec,
                    # the call less its set-up timed alone: the solver loop's own rate
                    "loop_particle_steps_per_s": particles * sum(steps) / max(sec - setup, 1e-9),
                    "loop_steps": max(steps),
                    "peak_mib": _peak_mib(device),
                }
                results["runs"].append(row)
                _write(args.out, results)
                print(
                    f"  {mode:9s} {b:5d} {first:8.2f} {sec:8.2f} {row['touches_per_s']:10.2f} "
                    f"{row['particle_steps_per_s']:10.3g} {row['loop_steps']:6d} {row['peak_mib']:9.0f} "
                    f"{setup:8.2f} {f'p{nproc}' if nproc else row['setup_threads']:>4} "
                    f"{row['loop_particle_steps_per_s']:10.3g}"
                )
            sim.close()
        if args.profile:
            profile_call(EIPSimulator(sensor, press, device=device), mesh, pos, dirs, strength, args.profile, device)
    if args.out:
        print(f"\nwrote {args.out}")


def profile_call(sim: EIPSimulator, mesh, pos, dirs, strength: dict, b: int, device: torch.device) -> None:
    """Print the ops that took the most device (CUDA) or CPU time in one eager ``press_batch`` of ``b`` touches."""
    from torch.profiler import ProfilerActivity, profile

    run_one(sim, mesh, pos, dirs, strength, b, device)  # warm
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=acts) as prof:
        run_one(sim, mesh, pos, dirs, strength, b, device)
    key = "cuda_time_total" if device.type == "cuda" else "cpu_time_total"
    print(f"\n  profile of one eager call, batch {b}, by {key}:")
    print(prof.key_averages().table(sort_by=key, row_limit=30, max_name_column_width=60))


if __name__ == "__main__":
    main()
