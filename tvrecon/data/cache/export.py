"""Copy a dataset's cache entries to another cache folder: the part of a shared cache that one preset reads.

A cache folder holds every preset and version ever generated into it. To train elsewhere (a GPU machine, a cluster
node, a colleague's laptop) only the entries of the splits a run reads need to travel:
``python -m tvrecon.data.generate preset=cls_paper_cpu export=/path/to/cache`` generates what is missing and then
copies each split's entries (``<root>/<key[:2]>/<key>.npz``, the same layout), so ``cache_dir=/path/to/cache`` there
finds every item cached. Each file is written to a temporary name and renamed, so an interrupted export leaves no
half-written entry; an entry already there with the same size is left as it is.
"""

from __future__ import annotations

import filecmp
import logging
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tvrecon.data.cache.store import SampleCache, cache_key
from tvrecon.utils.atomic import atomic_open

log = logging.getLogger(__name__)

__all__ = ["ExportStats", "export_entries"]


@dataclass
class ExportStats:
    """What :func:`export_entries` did: entries copied (``replaced`` of them over a differing copy), already there
    (the same bytes), missing from the source; bytes copied."""

    copied: int = 0
    replaced: int = 0  # of those copied: a differing copy was in the export folder
    present: int = 0
    missing: int = 0
    bytes_copied: int = 0


def export_entries(dataset: Any, dest: str | Path, indices: list[int] | None = None) -> ExportStats:
    """Copy the cache entries of ``dataset``'s items (all, or ``indices``) into the cache folder ``dest``.

    Args:
        dataset: a generated dataset (``spec(i)``, ``cache``, ``len``) whose cache holds the entries.
        dest: the target cache folder (created); must not be the dataset's own cache folder.
        indices: items to copy (default every item).
    Returns:
        :class:`ExportStats`; an item not cached in the source counts as ``missing`` (generate it first).
    """
    source: SampleCache = dataset.cache
    if not source.enabled:
        raise ValueError("the dataset has no cache folder (cache_dir=null): there is nothing to export")
    target = SampleCache(dest)
    if Path(dest).expanduser().resolve() == Path(str(source.root)).expanduser().resolve():
        raise ValueError(f"export folder {dest} is the dataset's own cache folder: give another folder")
    stats = ExportStats()
    for i in range(len(dataset)) if indices is None else indices:
        key = cache_key(dataset.spec(i))
        src, dst = source.path(key), target.path(key)
        if not src.is_file():
            stats.missing += 1
            continue
        size = src.stat().st_size
        if dst.is_file():
            if dst.stat().st_size == size and filecmp.cmp(src, dst, shallow=False):  # the bytes, not only the size
                stats.present += 1
                continue
            log.warning("export: %s differs from the cache's entry (a corrupt or stale copy): replaced", dst)
            stats.replaced += 1
        with atomic_open(dst, "wb") as out, open(src, "rb") as inp:  # a temp file renamed when complete
            shutil.copyfileobj(inp, out)
        stats.copied += 1
        stats.bytes_copied += size
    return stats
