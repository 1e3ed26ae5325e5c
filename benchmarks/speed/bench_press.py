"""Benchmark of the EIP press protocol (not a test).

    python -m benchmarks.speed.bench_press [--touches 4] [--threads 1] [--resolution 64]

Measures one default press (64x64 tactile image, 128 cells across the domain; wall and CPU time, split into scene
set-up and the solver loop) and the throughput of T touches pressed one at a time against the same T touches in one
batched solver loop (``press_batch``), reported as a ratio measured in the same run (absolute seconds drift on
shared machines).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
import trimesh

from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig


def timed(fn):
    """Run ``fn`` and return (result, wall seconds, CPU seconds of this process)."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def touches(T: int) -> tuple[list[trimesh.Trimesh], np.ndarray, np.ndarray]:
    """T presses on a sphere from directions spread over the upper hemisphere (seeded)."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.35)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(T, 3))
    d[:, 2] = -np.abs(d[:, 2]) - 0.5
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return [sphere] * T, -d * 0.35, d


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--touches", type=int, default=4)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    sim = EIPSimulator(SensorConfig(resolution=(args.resolution, args.resolution)), PressConfig())
    meshes, pos, dirs = touches(args.touches)
    print(
        f"torch {torch.__version__}, threads {torch.get_num_threads()}, pad {args.resolution}x{args.resolution}x"
        f"{sim.sensor.layers} = {sim.sensor.num_particles} particles, n_grid {sim.cfg.n_grid}"
    )

    sim.press(meshes[0], pos[0], dirs[0])  # warm-up (allocator, embree BVH)
    best = None
    for _ in range(args.repeats):
        (reading, wall, cpu) = timed(lambda: sim.press(meshes[0], pos[0], dirs[0]))
        if best is None or cpu < best[2]:
            best = (reading, wall, cpu)
    reading, wall, cpu = best
    setup, s_wall, s_cpu = timed(
        lambda: sim._setup(meshes[0], torch.tensor(pos[0]), torch.tensor(dirs[0]), *sim._configs({}))
    )
    rate = reading.steps * sim.sensor.num_particles / max(wall - s_wall, 1e-9)
    print(
        f"default press: {reading.steps} steps, depth {reading.depth:.2f} cells, max normal "
        f"{float(reading.image[2].max()):.2f} cells | wall {wall:.2f} s, CPU {cpu:.2f} s "
        f"(set-up incl. mesh collider: wall {s_wall:.2f} s, CPU {s_cpu:.2f} s) | "
        f"loop {rate / 1e6:.2f} M particle-steps/s"
    )

    (seq, seq_wall, seq_cpu) = timed(lambda: [sim.press(m, p, d) for m, p, d in zip(meshes, pos, dirs)])
    (bat, bat_wall, bat_cpu) = timed(lambda: sim.press_batch(meshes, pos, dirs))
    err = max(float((a.image - b.image).abs().max()) for a, b in zip(seq, bat))
    T = args.touches
    print(f"{T} touches sequential: wall {seq_wall:.2f} s ({T / seq_wall:.2f} touches/s), CPU {seq_cpu:.2f} s")
    print(f"{T} touches batched:    wall {bat_wall:.2f} s ({T / bat_wall:.2f} touches/s), CPU {bat_cpu:.2f} s")
    print(
        f"batched / sequential throughput: {seq_wall / bat_wall:.2f}x wall, {seq_cpu / bat_cpu:.2f}x CPU; "
        f"max |image difference| {err:.2e} cells; steps {[r.steps for r in bat]}"
    )


if __name__ == "__main__":
    main()
