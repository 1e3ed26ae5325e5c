"""A resumed run keeps the loss history it logged before its checkpoint.

Lightning's ``CSVLogger`` deletes ``<run>/csv/metrics.csv`` when it opens a log folder that already has one, so
``train.py ckpt_path=<run>/checkpoints/last.ckpt`` (resume) used to lose every epoch before the checkpoint from the
CSV and from ``loss_curves.png`` (TensorBoard appends a new events file and keeps them). :func:`rows_before_checkpoint`
reads the rows that the checkpoint covers (logged before its global step; rows logged after it, by a run cut off
mid-epoch, are logged again by the resumed run), and :func:`restore_csv_history` (``train.py``, when
``ckpt_path`` resumes a run) hands them to the new logger, which writes them ahead of the resumed run's rows.
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Sequence
from pathlib import Path

from lightning.pytorch.loggers import CSVLogger, Logger

from tvrecon.utils.checkpoint import load_checkpoint

__all__ = ["restore_csv_history", "rows_before_checkpoint"]

log = logging.getLogger(__name__)


def _progress(ckpt_path: str | Path) -> tuple[int, int]:
    """(epoch, global_step) stored in a Lightning checkpoint."""
    ckpt = load_checkpoint(ckpt_path)  # clear error for a missing or truncated file
    return int(ckpt.get("epoch", 0)), int(ckpt.get("global_step", 0))


def rows_before_checkpoint(metrics_csv: str | Path, ckpt_path: str | Path) -> list[dict[str, str]]:
    """Rows of an earlier run's ``metrics.csv`` that the checkpoint covers, empty cells dropped.

    Args:
        metrics_csv: the run's ``csv/metrics.csv`` (missing: nothing to keep).
        ckpt_path: the checkpoint the run resumes from.

    Returns:
        the rows logged before the checkpoint's global step (``step < global_step``: the resumed run logs that step
        again) and, where a row has an epoch, not after its epoch; in file order. Rows without a readable step are
        dropped; rows without an epoch (the learning-rate monitor's) are kept by their step.
    """
    path = Path(metrics_csv)
    if not path.is_file():
        return []
    epoch, step = _progress(ckpt_path)
    kept: list[dict[str, str]] = []
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            try:
                row_step = int(float(row.get("step") or "nan"))
                row_epoch = int(float(row["epoch"])) if row.get("epoch") else None
            except ValueError:
                continue
            if row_step < step and (row_epoch is None or row_epoch <= epoch):
                kept.append({k: v for k, v in row.items() if k is not None and v not in ("", None)})
    return kept


def restore_csv_history(loggers: Sequence[Logger], ckpt_path: str | Path) -> int:
    """Keep, in every CSV logger among ``loggers``, the rows its folder's old ``metrics.csv`` logged up to
    ``ckpt_path``: read them, open the logger (which deletes the old file, Lightning) and queue them ahead of
    everything it logs next, so its next ``save`` writes them with the resumed run's rows under one header. Call it
    before anything opens the loggers. Returns the number of rows kept.
    """
    restored = 0
    for lg in loggers:
        if not isinstance(lg, CSVLogger):
            continue
        rows = rows_before_checkpoint(Path(lg.log_dir) / "metrics.csv", ckpt_path)
        if not rows:
            continue
        writer = lg.experiment  # deletes the old metrics.csv; its rows were read above
        writer.metrics = [dict(r) for r in rows] + writer.metrics
        restored += len(rows)
        log.info("resumed run: the %d rows %s logged up to the checkpoint are kept", len(rows), lg.log_dir)
    return restored
