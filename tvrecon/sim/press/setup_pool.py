"""Touch set-up in worker processes (``EIPSimulator(setup_processes=N)``).

A touch's set-up (:func:`~tvrecon.sim.press.placement.place_touch`: frame, footprint rays, the mesh collider's
distance table) is host work: numpy, scipy and embree, about 0.1 CPU-s a touch of the authors' pad. On a GPU it was
measured at 59% of a batch-64 press of the paper scene on an H100 with 16 threads (3.06 of 5.15 s;
``benchmarks/README.md``): threads share one interpreter, and much of the set-up holds the GIL. Spawned processes
(one interpreter each, one torch thread) place the touches side by side on the CPU; the main process moves each
collider's tables to the simulator's device. The placements are those of the thread path bit for bit: the same
CPU code on the same arrays, the tables copied as they are (``tests/sim/press/test_setup_threads.py``).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import weakref
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.sim.press import placement
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig
from tvrecon.utils.process_lifetime import die_with_parent

__all__ = ["SetupPool"]


def _init_worker(parent_pid: int | None = None) -> None:
    if parent_pid is not None:  # kill -9 of the parent: the worker ends too instead of waiting on as an orphan
        die_with_parent(parent_pid)
    torch.set_num_threads(1)  # one process per core: the parallelism is the pool's


def _place_on_cpu(
    vertices: np.ndarray, faces: np.ndarray, position: Tensor, direction: Tensor, s: SensorConfig, p: PressConfig
) -> placement.Placement:
    """One touch's placement on the CPU, from the mesh's arrays (the mesh rebuilt as it was: no processing)."""
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return placement.place_touch(mesh, position, direction, s, p, torch.device("cpu"))


def _to_device(pl: placement.Placement, device: torch.device) -> placement.Placement:
    if pl.collider is None or device.type == "cpu":
        return pl
    return placement.Placement(
        R=pl.R, origin=pl.origin, direction=pl.direction, collider=pl.collider.to(device), reachable=pl.reachable
    )


class SetupPool:
    """``processes`` spawned worker processes placing touches; started on the first call, stopped with the owner.

    Args:
        processes: worker processes (>= 1).
    """

    def __init__(self, processes: int) -> None:
        if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
            raise ValueError(f"setup processes must be a positive int, got {processes!r}")
        self.processes = processes
        self._pool: ProcessPoolExecutor | None = None

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            # spawn: a forked child of a process that has used CUDA or OpenMP is unsafe
            self._pool = ProcessPoolExecutor(
                self.processes, mp_context=mp.get_context("spawn"), initializer=_init_worker, initargs=(os.getpid(),)
            )
            weakref.finalize(self, self._pool.shutdown, wait=False, cancel_futures=True)
        return self._pool

    def place(
        self,
        meshes: Sequence[trimesh.Trimesh],
        positions: Tensor,
        directions: Tensor,
        s: SensorConfig,
        p: PressConfig,
        device: torch.device,
    ) -> list[placement.Placement]:
        """The T touches' placements, in order, their colliders on ``device``.

        Args:
            meshes: T meshes (world coordinates). positions, directions: (T, 3) CPU tensors.
        Raises:
            the first failing touch's error (in touch order), as the thread path raises it.
        """
        positions, directions = positions.detach().cpu(), directions.detach().cpu()  # what a process can receive
        arrays: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # each distinct mesh's arrays, converted once
        futures = []
        try:
            pool = self._executor()
            for t, mesh in enumerate(meshes):
                if id(mesh) not in arrays:
                    arrays[id(mesh)] = (np.asarray(mesh.vertices), np.asarray(mesh.faces))
                futures.append(pool.submit(_place_on_cpu, *arrays[id(mesh)], positions[t], directions[t], s, p))
            return [_to_device(f.result(), device) for f in futures]
        except BrokenProcessPool as err:
            if self._pool is not None:  # the next call starts new workers
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = None
            raise RuntimeError(
                f"a touch set-up worker process died (of {self.processes}; killed, e.g. by the out-of-memory killer, "
                "or crashed in native code): this call's touches were not placed. Call again (new workers start), "
                "use fewer processes, or setup_processes=0 to set up in threads"
            ) from err
        finally:
            for f in futures:
                f.cancel()

    def close(self) -> None:
        """Stop the worker processes (a later call starts new ones)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
