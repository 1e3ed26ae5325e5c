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
per shard (``tvrecon/data/generation/launcher.py``, ``configs/generate.yaml``; job folders in
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
:mod:`tvrecon.data.cache.export`)::

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
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from tvrecon.data.cache.export import export_entries
from tvrecon.data.generation.args import OPTION_KEYS, parse_shard, parse_splits
from tvrecon.data.generation.pool import GenerateStats, combined, pregenerate_splits, shard_indices
from tvrecon.data.touches.report import contact_report
from tvrecon.sim.mpm.compiled.policy import AUTO
from tvrecon.utils.output_dir import check_writable_dir

__all__ = ["main"]

#: the data-config key that ``compile=true|false`` sets (``PressConfig.compile`` of the preset's ``press`` block)
COMPILE_KEY = "press.compile"


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
    from tvrecon.data.generation.launcher import is_multirun, multirun

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
    if opts.get("export"):  # refused before minutes of simulation, not after them
        check_writable_dir(opts["export"], "export=")
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
                f"({ex.bytes_copied / 2**20:.2f} MiB; {ex.replaced} of them over a differing copy), {ex.present} "
                f"already there (the same bytes), {ex.missing} not cached",
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
