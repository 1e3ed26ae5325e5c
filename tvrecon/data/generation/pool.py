"""The worker pool that pre-generates generated datasets into their cache: resumable, sharded, one pool for all splits.

:func:`pregenerate_splits` is what ``python -m tvrecon.data.generate`` (:mod:`tvrecon.data.generate`) and a datamodule
that makes its missing data before training call. Each worker process runs one torch thread; an item's touches are
simulated in one ``press_batch`` call. Items already in the cache (and readable) are skipped, so an interrupted run
resumes where it stopped. The progress bar counts touches (touches per second and ETA).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from tvrecon.data.cache.housekeeping import remove_stale_tmp
from tvrecon.data.cache.store import cache_key
from tvrecon.data.dataset_base import GeneratedDataset
from tvrecon.utils.cli_errors import RESUME_HINT
from tvrecon.utils.freed_memory import keep_freed_memory
from tvrecon.utils.process_lifetime import die_with_parent, spawnable_start_method

__all__ = [
    "GenerateStats",
    "WorkerDied",
    "combined",
    "pregenerate",
    "pregenerate_splits",
    "shard_indices",
    "touches_per_process",
]

log = logging.getLogger(__name__)


@dataclass
class GenerateStats:
    """What one :func:`pregenerate` call did."""

    items: int = 0  # items of this shard
    skipped: int = 0  # already cached
    generated: int = 0
    touches: int = 0  # touches simulated
    seconds: float = 0.0
    bytes_written: int = 0  # size of the entries of this shard now in the cache

    @property
    def touches_per_second(self) -> float:
        return self.touches / self.seconds if self.seconds > 0 else 0.0

    @property
    def bytes_per_1000(self) -> float:
        return 1000.0 * self.bytes_written / self.items if self.items else 0.0


def _rank_world() -> tuple[int, int]:
    rank = int(os.environ.get("RANK", os.environ.get("LOCAL_RANK", "0")))
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if not 0 <= rank < max(world, 1):
        raise ValueError(f"RANK/LOCAL_RANK={rank} is not in [0, WORLD_SIZE={world})")
    return rank, max(world, 1)


def shard_indices(
    num_items: int, shard: tuple[int, int] = (0, 1), rank_world: tuple[int, int] | None = None
) -> list[int]:
    """Indices of this process: ``shard=(i, n)`` combined with the launcher rank (``RANK``/``WORLD_SIZE`` env).

    The shards of all ``(i, rank)`` pairs partition ``range(num_items)``.
    """
    i, n = shard
    rank, world = rank_world if rank_world is not None else _rank_world()
    part, parts = i * world + rank, n * world
    return list(range(part, int(num_items), parts))


def touches_per_process(items: int, processes: int, per_item: int) -> int:
    """The most touches one of ``processes`` presses when they share ``items`` items of ``per_item`` touches."""
    return -(-int(items) // max(1, int(processes))) * int(per_item)


# ---------------------------------------------------------------------- worker side
_DATASETS: tuple[GeneratedDataset, ...] = ()


def _init_worker(datasets: tuple[GeneratedDataset, ...], parent_pid: int | None = None) -> None:
    global _DATASETS
    if parent_pid is not None:  # kill -9 of the parent: the worker ends too instead of generating on as an orphan
        die_with_parent(parent_pid)
    # Ctrl-C reaches the whole process group: the main process alone answers it (one line, exit 130) and stops the
    # workers, instead of each worker printing its own KeyboardInterrupt traceback (ignored from their start too)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # started with SIGINT blocked (see _pool_generate): now ignored, unblock
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    torch.set_num_threads(1)
    keep_freed_memory()  # a press step's temporaries stay in the process for the next step (tvrecon.utils.freed_memory)
    _DATASETS = datasets


def _work(job: tuple[int, int]) -> tuple[tuple[int, int], bool]:
    """Generate item ``index`` of the worker's dataset ``split`` (``job = (split, index)``)."""
    assert _DATASETS, "worker not initialised"
    split, index = job
    _, hit = raw_named(_DATASETS[split], index)
    return job, hit


class ItemFailed(RuntimeError):
    """An item could not be generated (an error of a type of its own); the message names the item and the error."""


def raw_named(ds: GeneratedDataset, index: int) -> tuple[dict, bool]:
    """``ds.raw(index)``; an error is raised again naming the item (a run of thousands of items otherwise ends on an
    error that does not say which object to look at): the same type for Python's own exceptions (a ValueError stays
    a usage error for the CLI's exit code), :class:`ItemFailed` for others."""
    try:
        return ds.raw(index)
    except Exception as err:  # noqa: BLE001 - re-raised with the item's name
        name, instance = ds.object_of(index)
        msg = (
            f"split {ds.split!r} item {index} ({name}, instance {instance}): {err}. The items finished before it are "
            "cached: the same command goes on from them"
        )
        named: Exception = ItemFailed(f"{type(err).__name__}: {msg}")
        if type(err).__module__ == "builtins":
            try:
                named = type(err)(msg)
            except TypeError:  # a type built from more than a message (UnicodeDecodeError): ItemFailed
                pass
        raise named from err


class WorkerDied(RuntimeError):
    """A worker process of :func:`pregenerate` died (killed by a signal, e.g. the OOM killer's SIGKILL)."""


def _pool_generate(
    datasets: Sequence[GeneratedDataset], todo: list[tuple[int, int]], workers: int, desc: Sequence[str]
) -> Iterator[tuple[int, int]]:
    """Generate ``todo`` (``(dataset, index)`` pairs) in ``workers`` spawned processes; yields each pair as it is done.

    One pool for every split: the workers start (and compile) once, and a small split does not end on one worker
    while the other waits for the next split's pool (measured: val and test at 70% of train's
    rate, each in its own pool).

    A ``ProcessPoolExecutor`` (not ``multiprocessing.Pool``, which waits forever for a worker killed by ``kill -9``)
    notices a dead worker at once: the pool is stopped and :class:`WorkerDied` names the signal and how to resume.
    """
    ctx = mp.get_context("spawn")  # fork after torch/OpenMP use is unsafe
    init_args = (tuple(datasets), os.getpid())  # the workers end with this process (kill -9 of it too)
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=init_args)
    procs: list[mp.process.BaseProcess] = []
    clean = False
    try:
        # the workers start with SIGINT blocked (the mask is inherited through exec), so a Ctrl-C while they import
        # is not a traceback per worker: the main process alone answers it. Blocked, not ignored, in the main process
        # too: a Ctrl-C that arrives while the workers are spawned is delivered when the mask is lifted, not lost (with
        # SIG_IGN here a loaded machine lost it, and the run went on to exit 0)
        in_main = threading.current_thread() is threading.main_thread()
        if not hasattr(signal, "pthread_sigmask"):  # no signal masks on this platform: ignore it while spawning
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if in_main else None
        elif in_main:
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            with spawnable_start_method():  # inside a joblib launcher's job too
                futures = [pool.submit(_work, i) for i in todo]
        finally:
            if in_main and hasattr(signal, "pthread_sigmask"):
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
            elif in_main:
                signal.signal(signal.SIGINT, previous)
        procs = list(pool._processes.values())  # all spawned by now; kept to name the signal of a dead one
        for fut in as_completed(futures):
            yield fut.result()[0]
        clean = True
    except BrokenProcessPool as err:
        raise WorkerDied(_dead_worker_message(procs, desc)) from err
    finally:
        pool.shutdown(wait=clean, cancel_futures=True)
        for p in procs:  # Ctrl-C, SIGTERM or an error: no worker outlives the run
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=5)


def _dead_worker_message(procs: list[mp.process.BaseProcess], desc: str | Sequence[str]) -> str:
    # the executor's manager thread reaps the workers too: a poll that loses that race reads no exit code for a
    # process already dead, until the manager thread has stored it, so ask again for a few seconds
    deadline = time.monotonic() + 5.0
    for p in procs:
        p.join(timeout=1)
        while p.exitcode is None and time.monotonic() < deadline:
            time.sleep(0.05)
    dead = [p for p in procs if p.exitcode is not None and p.exitcode != 0]

    # the pool SIGTERMs the others itself, and a survivor may die of its own as the queues close under it, with an
    # error or a signal (seen under load: the message named that worker, not the one killed). SIGKILL only comes from
    # outside (the OOM killer, kill -9): it first, then another signal, then an error, then SIGTERM
    def rank(p: mp.process.BaseProcess) -> int:
        code = p.exitcode
        return 0 if code == -signal.SIGKILL else 3 if code == -signal.SIGTERM else 1 if code < 0 else 2

    killed = sorted(dead, key=rank)  # stable: the pool's order within a rank
    if killed and killed[0].exitcode is not None and killed[0].exitcode < 0:
        how = f"was killed by {signal.Signals(-killed[0].exitcode).name}"
        if killed[0].exitcode == -signal.SIGKILL:
            how += " (the kernel's out-of-memory killer sends it when memory runs out; fewer workers= use less)"
    elif killed:
        how = f"exited with status {killed[0].exitcode}"
    else:
        how = "died"
    pid = f" (pid {killed[0].pid})" if killed else ""
    names = [desc] if isinstance(desc, str) else [d for d in desc if d]
    split = f" of split{'s' if len(names) > 1 else ''} {', '.join(map(repr, names))}" if any(names) else ""
    return (
        f"a generate worker process{pid}{split} {how}; the pool was stopped. The items finished so far are cached: "
        f"{RESUME_HINT}"
    )


def pregenerate(
    dataset: GeneratedDataset,
    workers: int | None = None,
    shard: tuple[int, int] = (0, 1),
    rank_world: tuple[int, int] | None = None,
    desc: str = "",
    progress: bool = True,
) -> GenerateStats:
    """Generate every item of ``dataset`` (this process's shard) that is not yet in its cache.

    Args:
        dataset: a generated dataset with a cache directory.
        workers: worker processes (default ``os.cpu_count()``); 1 runs in this process.
        shard: ``(i, n)``: this call handles items ``j`` with ``j % (n * world) == i * world + rank``.
        rank_world: ``(rank, world_size)``; default from the ``RANK``/``LOCAL_RANK``/``WORLD_SIZE`` environment.
        desc: progress bar label.
        progress: show the tqdm bar.
    Returns:
        :class:`GenerateStats`.
    """
    return pregenerate_splits({desc: dataset}, workers, shard, rank_world, progress)[0]


def pregenerate_splits(
    datasets: Mapping[str, GeneratedDataset],
    workers: int | None = None,
    shard: tuple[int, int] = (0, 1),
    rank_world: tuple[int, int] | None = None,
    progress: bool = True,
) -> list[GenerateStats]:
    """:func:`pregenerate` of several datasets (``name -> dataset``, e.g. a preset's splits) in one pool of workers.

    The workers start and compile once for all of them and take the next item of any split as they free up, so the
    splits do not each pay a pool's start and its one-worker tail. Items are handed out in the datasets' order.

    Returns:
        One :class:`GenerateStats` per dataset, in order. Their ``seconds`` count from the pool's start to the end of
        that dataset's last item (the datasets share the time), so the run's throughput is the sum of their touches
        over the last ``seconds`` (:func:`combined`).
    """
    if workers is None:
        workers = os.cpu_count() or 1
    elif isinstance(workers, bool) or int(workers) != workers or workers < 1:  # 0 once meant "all cores" silently
        raise ValueError(f"workers must be a whole number >= 1 (leave it out for one per core), got {workers!r}")
    workers = int(workers)
    names, sets = list(datasets), list(datasets.values())
    for ds in sets:
        if not ds.cache.enabled:
            raise ValueError("pregenerate needs a dataset with a cache directory (cache_dir=None disables caching)")
    indices = [shard_indices(len(ds), shard, rank_world) for ds in sets]
    stats = [GenerateStats(items=len(ix)) for ix in indices]
    todo: list[tuple[int, int]] = []
    for k, (ds, ix) in enumerate(zip(sets, indices)):
        remove_stale_tmp(ds.cache.root)  # temporary files of killed runs, older than this job
        mine = [i for i in ix if ds.cache.load(cache_key(ds.spec(i))) is None]
        stats[k].skipped = len(ix) - len(mine)
        if mine:  # a read-only cache is reported before any worker starts simulating
            ds.cache.check_writable(cache_key(ds.spec(mine[0])))
        todo += [(k, i) for i in mine]
    per_item = [ds.touches_per_item for ds in sets]
    procs = 1 if workers == 1 or len(todo) <= 1 else min(workers, len(todo))
    share = touches_per_process(len(todo), procs, max(per_item))  # the busiest process's touches, all splits
    for k, ds in enumerate(sets):  # compile="auto": settled before the datasets go to the workers
        if any(j == k for j, _ in todo):
            ds.plan_compile(share)
    left = [sum(1 for j, _ in todo if j == k) for k in range(len(sets))]
    label = ", ".join(n for n, k in zip(names, left) if k) if len(sets) > 1 else names[0]
    bar = tqdm(
        total=sum(per_item[k] for k, _ in todo),
        desc=f"generate {label}".strip(),
        unit="touch",
        disable=not progress or not todo,
        dynamic_ncols=True,
    )
    start = time.perf_counter()

    def done(k: int) -> None:
        stats[k].generated += 1
        stats[k].touches += per_item[k]
        stats[k].seconds = time.perf_counter() - start
        bar.update(per_item[k])

    try:
        if procs == 1:
            if todo:
                keep_freed_memory()  # as each worker does (_init_worker)
            for k, i in todo:
                raw_named(sets[k], i)
                done(k)
        else:
            for k, _ in _pool_generate(sets, todo, procs, [n for n, c in zip(names, left) if c]):
                done(k)
    finally:
        bar.close()
        if not todo:
            for st in stats:
                st.seconds = time.perf_counter() - start
    for st, ds, ix in zip(stats, sets, indices):
        st.bytes_written = sum(p.stat().st_size for i in ix if (p := ds.cache.path(cache_key(ds.spec(i)))).is_file())
    return stats


def combined(stats: Sequence[GenerateStats]) -> GenerateStats:
    """The run of several :func:`pregenerate_splits` datasets as one: summed counts over the last one's time."""
    out = GenerateStats()
    for st in stats:
        out.items += st.items
        out.skipped += st.skipped
        out.generated += st.generated
        out.touches += st.touches
        out.bytes_written += st.bytes_written
        out.seconds = max(out.seconds, st.seconds)
    return out
