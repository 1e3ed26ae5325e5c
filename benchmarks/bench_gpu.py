"""Press throughput against batch size on one device: touches/s, particle-steps/s, peak memory, ops and syncs per step.

    python benchmarks/bench_gpu.py                                   # CPU: batches 1,2,4,8, eager and compiled
    python benchmarks/bench_gpu.py --device cuda --out bench_gpu.json   # a GPU: batches 1 .. 1024 until memory runs out

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

Ops and syncs per step (``--count-batch``, default 4, eager only): the aten ops dispatched during one ``press_batch``
call, counted with a ``TorchDispatchMode``, less those of the same call stopped after one step, per further step;
also without the ops that only make views (no kernel on a GPU). A host sync is an op whose result the host must
wait for: ``_local_scalar_dense`` (``.item()``, ``bool(tensor)``), ``nonzero``, ``masked_select``, ``unique*``,
``repeat_interleave`` with tensor repeats and boolean-mask indexing.
On a GPU each op is a kernel launch and each sync a stall. CUDA graphs are not measured: the press loop checks its
stop rule on the host every step, so the step cannot be captured yet.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import torch
import trimesh
from torch.utils._python_dispatch import TorchDispatchMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hydra.utils import instantiate  # noqa: E402

from tvrecon.data.presets import compose_preset  # noqa: E402
from tvrecon.data.touches import sample_touches  # noqa: E402
from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig  # noqa: E402

# ops that only make a new view of existing memory: no kernel on a GPU
VIEW_OPS = frozenset(
    "view _unsafe_view alias as_strided slice select expand unsqueeze squeeze transpose t permute detach "
    "split unbind chunk narrow diagonal reshape unflatten".split()
)
SYNC_OPS = ("_local_scalar_dense", "nonzero", "masked_select", "unique", "_unique", "unique_dim", "unique_consecutive")


class OpCounter(TorchDispatchMode):
    """Counts aten ops (by overload packet name) and the host-syncing ones among them."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: Counter[str] = Counter()
        self.syncs: Counter[str] = Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # noqa: ANN001 (torch's signature)
        name = func.overloadpacket.__name__
        self.ops[name] += 1
        if name in SYNC_OPS:
            self.syncs[name] += 1
        elif name == "repeat_interleave" and isinstance(args[0] if args else None, torch.Tensor) and len(args) > 1:
            if isinstance(args[1], torch.Tensor):
                self.syncs[name] += 1
        elif name == "index" and any(
            isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in (args[1] if len(args) > 1 else ()) or ()
        ):
            self.syncs["index(bool mask)"] += 1
        return func(*args, **(kwargs or {}))


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


def _counted(sim: EIPSimulator, mesh, pos, dirs, strength: dict, b: int, **limit) -> tuple[OpCounter, int]:
    counter = OpCounter()
    with counter:
        readings = sim.press_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength, **limit)
    return counter, max(int(r.steps) for r in readings)


def count_ops(sensor, press, mesh, pos, dirs, strength: dict, b: int, device: torch.device) -> dict:
    """Aten ops and host syncs per loop step of one eager ``press_batch`` of ``b`` touches.

    Per step = (a whole press - the same press stopped after its first step) / (its steps - 1): the set-up (placement,
    SDF, pad) and the read-out, paid once per call, cancel.
    """
    sim = EIPSimulator(sensor, press, device=device, compile=False)
    sim.press_batch(mesh, _tile(pos, b), _tile(dirs, b), **strength)  # warm caches (placement, SDF) like a real run
    one, _ = _counted(sim, mesh, pos, dirs, strength, b, max_steps=1)
    full, steps = _counted(sim, mesh, pos, dirs, strength, b)
    n = max(steps - 1, 1)
    ops = full.ops - one.ops
    syncs = full.syncs - one.syncs
    return {
        "batch": b,
        "loop_steps": steps,
        "ops_per_step": sum(ops.values()) / n,
        "launch_ops_per_step": sum(v for k, v in ops.items() if k not in VIEW_OPS) / n,
        "syncs_per_step": sum(syncs.values()) / n,
        "ops_per_call_outside_steps": sum(one.ops.values()) - sum(ops.values()) / n,
        "syncs_by_op": {k: round(v / n, 2) for k, v in syncs.most_common()},
        "top_ops": {k: round(v / n, 1) for k, v in ops.most_common(8)},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--scenes", default="paper,bench", help="comma-separated: " + ", ".join(SCENES))
    parser.add_argument("--modes", default="eager,compiled", help="comma-separated: eager, compiled")
    parser.add_argument("--batches", default=None, help="comma-separated batch sizes (default 1..8 CPU, 1..1024 CUDA)")
    parser.add_argument("--repeats", type=int, default=1, help="timed calls per (scene, mode, batch)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--count-batch", type=int, default=4, help="batch of the op/sync count (0: skip)")
    parser.add_argument("--out", type=Path, default=None, help="write every figure to this JSON file")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")  # thin-part contact warnings of the paper scene: not what is measured here
    device = torch.device(args.device)
    on_cuda = device.type == "cuda"
    batches = [int(b) for b in args.batches.split(",")] if args.batches else [2**k for k in range(11 if on_cuda else 4)]
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
            c = count_ops(sensor, press, mesh, pos, dirs, strength, args.count_batch, device)
            results["counts"].append({"scene": scene, **c})
            print(
                f"  eager, batch {c['batch']}: {c['ops_per_step']:.0f} aten ops "
                f"({c['launch_ops_per_step']:.0f} not views) and {c['syncs_per_step']:.1f} host syncs per step "
                f"({c['loop_steps']} steps; {c['ops_per_call_outside_steps']:.0f} ops per call "
                f"outside the steps); syncs {c['syncs_by_op']}; most ops {c['top_ops']}"
            )
        print(
            f"  {'mode':9s} {'batch':>5s} {'first s':>8s} {'s/call':>8s} {'touches/s':>10s} {'p-steps/s':>10s} "
            f"{'steps':>6s} {'peak MiB':>9s}"
        )
        for mode in args.modes.split(","):
            sim = EIPSimulator(sensor, press, device=device, compile=mode == "compiled")
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
                steps = [int(r.steps) for r in readings]
                row = {
                    "scene": scene,
                    "mode": mode,
                    "batch": b,
                    "first_s": first,
                    "s_per_call": sec,
                    "touches_per_s": b / sec,
                    "particle_steps_per_s": particles * sum(steps) / sec,
                    "loop_steps": max(steps),
                    "peak_mib": _peak_mib(device),
                }
                results["runs"].append(row)
                print(
                    f"  {mode:9s} {b:5d} {first:8.2f} {sec:8.2f} {row['touches_per_s']:10.2f} "
                    f"{row['particle_steps_per_s']:10.3g} {row['loop_steps']:6d} {row['peak_mib']:9.0f}"
                )
    if args.out:
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(json.dumps(results, indent=1))
        tmp.replace(args.out)
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
