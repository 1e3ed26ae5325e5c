"""Pre-generate a data preset into the cache, in parallel, resumable and sharded.

Usage::

    python -m tvrecon.data.generate preset=small                      # every split of configs/data/small.yaml
    python -m tvrecon.data.generate preset=cls_small splits=train workers=2
    python -m tvrecon.data.generate preset=paper --shard 3/8           # this process does items i % 8 == 3
    python -m tvrecon.data.generate preset=tiny train.num_samples=4 sensor.resolution=[8,8] cache_dir=/tmp/c
    python -m tvrecon.data.generate preset=paper workers=2 compile=false  # force the eager step (default: auto)

Arguments are ``key=value``: ``preset`` (a YAML name in ``configs/data``, default ``small``), ``splits``
(comma-separated or a list, ``[val,test]``; default all configured), ``workers`` (processes, default all cores),
``shard=i/n`` (or ``--shard i/n``), ``compile`` (``true``/``false``/``auto``: the presses' fused kernels; short for
the data-config override ``press.compile=...`` of ``PressConfig.compile``, which the worker processes receive with
the config; readings equal the eager ones to float32 round-off and the cache key does not change. The presets'
``auto`` compiles in each worker that presses enough touches to pay the compile back: 500 small-pad touches on a CPU
with a C++ compiler, 100 once the compile cache ``<cache_dir>/torch_compile`` is warm, 75,000 on CUDA (about 4,800 of
the authors' pad); the log says what it chose); everything else is a Hydra override of the data config
(``cache_dir=...``, ``train.num_samples=8``).
Under a launcher that sets ``RANK``/``LOCAL_RANK`` and ``WORLD_SIZE`` (Lightning, torchrun, a cluster array job),
each rank takes its own share of the shard, so a cluster generates in parallel.

Shards as the jobs of a Hydra launcher: the same command with ``--multirun`` (``-m``) and a list of shards runs one job
per shard (``tvrecon/data/generate_launcher.py``, ``configs/generate.yaml``; job folders in
``logs/generate/multirun/<time>``)::

    # local processes (hydra-joblib-launcher, in the dev extra): n_jobs x workers processes in all
    python -m tvrecon.data.generate --multirun preset=small shard=0/4,1/4,2/4,3/4 workers=1 \
        hydra/launcher=joblib hydra.launcher.n_jobs=2
    # one SLURM job per shard (pip install -e '.[cluster]': hydra-submitit-launcher)
    python -m tvrecon.data.generate --multirun preset=paper shard=$(seq -s, -f '%g/16' 0 15) workers=8 \
        hydra/launcher=submitit_slurm hydra.launcher.partition=cpu hydra.launcher.cpus_per_task=8 \
        hydra.launcher.timeout_min=240

``export=DIR`` copies each split's cached entries (this shard's) into the cache folder DIR after generating them: the
part of a shared cache that this preset reads, to take to a GPU machine or a cluster (``cache_dir=DIR`` there;
:mod:`tvrecon.data.cache_export`)::

    python -m tvrecon.data.generate preset=cls_paper_cpu library.protocol=shared_base export=/tmp/cls_paper_cpu

``preset``, ``splits``, ``workers``, ``shard``, ``compile`` and ``export`` can be swept (``a,b``); data overrides are
passed unchanged to every job. The shards of all jobs write exactly the cache entries of a single-process run, and each
job skips the items already cached: rerun the same command after a job failed or hit its time limit.

Each worker process runs one torch thread; an item's touches are simulated in one ``press_batch`` call. Items
already in the cache (and readable) are skipped, so an interrupted run resumes where it stopped. The progress bar
counts touches (touches per second and ETA); the final line reports throughput and disk use.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm.auto import tqdm

from tvrecon.data.cache import cache_key
from tvrecon.data.cache_export import export_entries
from tvrecon.data.cache_housekeeping import remove_stale_tmp
from tvrecon.data.generate_args import OPTION_KEYS, parse_shard, parse_splits
from tvrecon.data.generated_dataset import GeneratedDataset
from tvrecon.data.touch_report import contact_report
from tvrecon.sim.mpm.compiled.policy import AUTO
from tvrecon.utils.cli_errors import RESUME_HINT
from tvrecon.utils.heap import keep_freed_memory

__all__ = [
    "GenerateStats",
    "WorkerDied",
    "combined",
    "pregenerate",
    "pregenerate_splits",
    "shard_indices",
    "touches_per_process",
    "main",
]

log = logging.getLogger(__name__)

#: the data-config key that ``compile=true|false`` sets (``PressConfig.compile`` of the preset's ``press`` block)
COMPILE_KEY = "press.compile"


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


def _init_worker(datasets: tuple[GeneratedDataset, ...]) -> None:
    global _DATASETS
    # Ctrl-C reaches the whole process group: the main process alone answers it (one line, exit 130) and stops the
    # workers, instead of each worker printing its own KeyboardInterrupt traceback (ignored from their start too)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # started with SIGINT blocked (see _pool_generate): now ignored, unblock
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    torch.set_num_threads(1)
    keep_freed_memory()  # a press step's temporaries stay in the process for the next step (tvrecon.utils.heap)
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
    while the other waits for the next split's pool (measured: val and test at 70% of train's rate, each in
    its own pool).

    A ``ProcessPoolExecutor`` (not ``multiprocessing.Pool``, which waits forever for a worker killed by ``kill -9``)
    notices a dead worker at once: the pool is stopped and :class:`WorkerDied` names the signal and how to resume.
    """
    ctx = mp.get_context("spawn")  # fork after torch/OpenMP use is unsafe
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(tuple(datasets),))
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
    for p in procs:
        p.join(timeout=1)
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


# ---------------------------------------------------------------------- CLI
def _parse(argv: Sequence[str]) -> tuple[dict[str, str], list[str]]:
    opts: dict[str, str] = {}
    overrides: list[str] = []
    args = list(argv)
    while args:
        a = args.pop(0)
        if a in ("-h", "--help"):
            print(__doc__)
            raise SystemExit(0)
        if a == "--shard":
            if not args:
                raise ValueError("--shard needs a value i/n")
            opts["shard"] = args.pop(0)
        elif a.startswith("--shard="):
            opts["shard"] = a.split("=", 1)[1]
        elif "=" in a and a.split("=", 1)[0] in OPTION_KEYS:
            k, v = a.split("=", 1)
            opts[k] = v
        elif a.split("=", 1)[0].lstrip("+~").startswith(("hydra.", "hydra/")):  # else ignored by compose: say so
            raise ValueError(f"{a!r} is a Hydra setting: it takes effect with --multirun only (see --help)")
        elif "=" in a or (a.startswith("~") and len(a) > 1):  # ~key: Hydra's deletion of a key
            overrides.append(a)
        else:
            raise ValueError(f"unexpected argument {a!r}; use key=value (see --help)")
    return opts, overrides


def main(argv: Sequence[str] | None = None) -> list[GenerateStats]:
    """CLI entry point; returns the stats of every split generated ([] with ``--multirun``: the jobs print theirs)."""
    args = list(sys.argv[1:] if argv is None else argv)
    from tvrecon.data.generate_launcher import is_multirun, multirun

    if is_multirun(args):  # the shards as the jobs of a Hydra launcher; each job calls main without --multirun
        return multirun(args, run=main, usage=__doc__ or "")
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    opts, overrides = _parse(args)
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if in_main else None
    if in_main:  # SIGTERM -> SystemExit, so the pool's context manager stops its workers
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    try:
        return _run(opts, overrides + _compile_override(opts, overrides))
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)


def _compile_override(opts: dict[str, str], overrides: Sequence[str]) -> list[str]:
    """``compile=true|false|auto`` as the data-config override ``press.compile=...`` ([] without ``compile=``): the
    datasets, and so the worker processes they are pickled into, carry it in their ``PressConfig``."""
    if "compile" not in opts:
        return []
    auto = opts["compile"].strip().lower() == AUTO
    flag = AUTO if auto else str(_flag(opts["compile"], "compile", also=AUTO)).lower()
    if any(o.split("=", 1)[0].lstrip("+~") == COMPILE_KEY for o in overrides):
        raise ValueError(f"give compile=... or {COMPILE_KEY}=..., not both (compile=true is {COMPILE_KEY}=true)")
    return [f"{COMPILE_KEY}={flag}"]


def _flag(value: str, name: str, also: str | None = None) -> bool:
    """``true``/``false`` (also 1/0, yes/no, any case) of a ``key=value`` argument; ValueError naming ``name`` (and
    the other accepted word ``also`` in its message)."""
    v = value.strip().lower()
    if v in ("true", "1", "yes"):
        return True
    if v in ("false", "0", "no"):
        return False
    raise ValueError(f"{name} must be true or false{f' or {also}' if also else ''}, got {value!r}")


def _run(opts: dict[str, str], overrides: list[str]) -> list[GenerateStats]:
    from hydra.utils import instantiate

    from tvrecon.data.presets import compose_preset

    try:  # checked before the preset is built: `workers=abc` must name workers, not end in int()'s message
        workers = int(opts["workers"]) if opts.get("workers") else None
    except ValueError:
        raise ValueError(f"workers must be a whole number of processes, got {opts['workers']!r}") from None
    cfg = compose_preset(opts.get("preset", "small"), overrides)
    dm = instantiate(cfg, _convert_="all")
    shard = parse_shard(opts.get("shard", "0/1"))
    splits = parse_splits(opts["splits"], dm.available_splits()) if opts.get("splits") else dm.available_splits()
    results = []
    cache = getattr(dm, "cache_dir", None)
    print(f"cache: {Path(cache).expanduser().resolve() if cache else 'disabled (cache_dir=null)'}", flush=True)
    # jobs of a multirun interleave: their lines name the shard
    labels = {name: name if shard == (0, 1) else f"{name} shard {shard[0]}/{shard[1]}" for name in splits}
    sets = {labels[name]: dm.make_dataset(name) for name in splits}
    results = pregenerate_splits(sets, workers=workers, shard=shard)  # one pool of workers for every split
    together = len(results) > 1 and sum(st.generated > 0 for st in results) > 1
    for (label, ds), st in zip(sets.items(), results):
        timing = (
            f"done {st.seconds:.1f} s into the run"  # the splits shared the workers: the rate is the run's (below)
            if together
            else f"in {st.seconds:.1f} s = {st.touches_per_second:.2f} touches/s"
        )
        print(
            f"[{label}] {st.items} items in shard, {st.skipped} cached, {st.generated} generated: {st.touches} touches "
            f"{timing}; cache {st.bytes_written / 2**20:.2f} MiB "
            f"= {st.bytes_per_1000 / 2**20:.1f} MiB per 1000 samples ({Path(str(ds.cache.root)).resolve()})",
            flush=True,
        )
        print(f"[{label}] {contact_report(ds).line()}", flush=True)  # blank touches per class (thin parts)
        if opts.get("export"):
            ex = export_entries(ds, opts["export"], indices=shard_indices(len(ds), shard))
            print(
                f"[{label}] exported to {Path(opts['export']).expanduser().resolve()}: {ex.copied} entries copied "
                f"({ex.bytes_copied / 2**20:.2f} MiB), {ex.present} already there, {ex.missing} not cached",
                flush=True,
            )
    if together:
        run = combined(results)
        print(
            f"[{', '.join(sets)}] {run.generated} items generated: {run.touches} touches in {run.seconds:.1f} s = "
            f"{run.touches_per_second:.2f} touches/s",
            flush=True,
        )
    return results


if __name__ == "__main__":
    from tvrecon.utils.cli_errors import run_cli

    run_cli(main, prog="python -m tvrecon.data.generate", resume=True)  # errors: one line, exit 2/1/130
