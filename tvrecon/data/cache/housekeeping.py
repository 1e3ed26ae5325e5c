"""Housekeeping of the sample cache at the start of a job: stale temporary files, and what is left to simulate.

- A run killed while writing a cache entry (``kill -9``, the OOM killer, a power cut) leaves its ``.*.tmp`` file
  behind (the atomic write never reached its rename). :func:`remove_stale_tmp` removes those older than the running
  job, at the start of ``generate`` and of a datamodule's setup; files younger than a grace period are kept, since
  another job writing to the same cache may be in the middle of one.
- The first epoch on an empty cache simulates every touch on the fly, which takes a while without a word:
  :func:`announce_uncached` logs how many touches are about to be simulated and where they are cached.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

from tvrecon.utils.atomic import tmp_writer_gone

__all__ = ["announce_uncached", "job_start_time", "remove_stale_tmp", "uncached_items"]

log = logging.getLogger(__name__)

#: a temporary file younger than this may belong to another job writing now: it is kept
GRACE_SECONDS = 600.0
#: splits larger than this are sampled (evenly spaced items) to estimate what is uncached
EXACT_COUNT_LIMIT = 2000


def job_start_time() -> float:
    """When this process started (epoch seconds, from ``/proc``), or now where ``/proc`` is not available."""
    try:
        ticks = int(Path("/proc/self/stat").read_text().rsplit(") ", 1)[1].split()[19])
        boot = next(
            float(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines() if line.startswith("btime")
        )
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return time.time()


def remove_stale_tmp(root: str | Path | None, started: float | None = None, grace_s: float = GRACE_SECONDS) -> int:
    """Remove the ``*.tmp`` files of the cache ``root`` (and its shard folders) older than the running job, and at
    once those whose writer (named in the file's name: ``tvrecon.utils.atomic.tmp_prefix``) was a process of this host
    that no longer runs (a ``generate`` killed a moment ago; the grace period would have kept its files).

    Args:
        root: the cache directory (None or missing: nothing to do).
        started: the job's start, epoch seconds (default :func:`job_start_time`).
        grace_s: files modified within this many seconds are kept whatever ``started`` is (another job's write).
    Returns:
        The number of files removed (logged at INFO when > 0).
    """
    if root is None or not Path(root).is_dir():
        return 0
    cutoff = min(job_start_time() if started is None else started, time.time() - grace_s)
    removed = 0
    for path in [*Path(root).glob("*.tmp"), *Path(root).glob("*/*.tmp")]:
        try:
            if path.is_file() and (tmp_writer_gone(path.name) or path.stat().st_mtime < cutoff):
                path.unlink()
                removed += 1
        except FileNotFoundError:  # another job removed or renamed it meanwhile
            continue
    if removed:
        log.info("removed %d stale temporary file(s) of killed runs from the cache %s", removed, root)
    return removed


def uncached_items(dataset: Any, limit: int = EXACT_COUNT_LIMIT) -> tuple[int, bool]:
    """How many items of ``dataset`` (a ``GeneratedDataset``) have no cache entry yet.

    Returns:
        ``(count, exact)``: exact for up to ``limit`` items, else estimated from ``limit`` evenly spaced items.
    """
    n = len(dataset)
    if n <= limit:
        return sum(not dataset.is_cached(i) for i in range(n)), True
    picks = [round(i * (n - 1) / (limit - 1)) for i in range(limit)]
    missing = sum(not dataset.is_cached(i) for i in picks)
    return round(missing * n / limit), False


def announce_uncached(name: str, dataset: Any) -> int:
    """Log how many touches of split ``name`` will be simulated on the fly and where they are cached.

    Returns:
        The number of uncached items (estimated for large splits; 0 when everything is cached).
    """
    cache = getattr(dataset, "cache", None)
    per_item = int(getattr(dataset, "touches_per_item", 0))
    if cache is None or not cache.enabled:
        log.info(
            "split %r: %d items, caching disabled (cache_dir=null): every epoch simulates their touches again",
            name,
            len(dataset),
        )
        return len(dataset)
    count, exact = uncached_items(dataset)
    if count:
        about = "" if exact else "about "
        log.info(
            "split %r: %s%d of %d items are not cached yet: they are simulated on the fly as they are first read "
            "(%s%d touches), cached in %s. `python -m tvrecon.data.generate preset=<data preset>` does it ahead, "
            "in parallel",
            name,
            about,
            count,
            len(dataset),
            about,
            count * per_item,
            Path(str(cache.root)).resolve(),
        )
    return count
