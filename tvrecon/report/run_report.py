"""A run's test results on disk: ``metrics.json`` and the paper tables, written by ``train.py`` and ``eval.py``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tvrecon.report.cls_report import write_classification_plots
from tvrecon.report.tables import build_tables, format_tables, write_tables
from tvrecon.utils.atomic import atomic_write_text

__all__ = ["report_tables", "save_results"]


def save_results(result: dict[str, Any], out_dir: str | Path) -> Path:
    """Write a test result dict as ``<out_dir>/metrics.json`` (atomic)."""
    return atomic_write_text(Path(out_dir) / "metrics.json", json.dumps(result, indent=2, sort_keys=True))


def report_tables(results: list[dict[str, Any]], out_dir: str | Path, echo: bool = True) -> str:
    """Build the paper tables the results allow, write them to ``<out_dir>/tables`` and print them."""
    tables = build_tables(results)
    if not tables:
        return ""
    paths = write_tables(tables, Path(out_dir) / "tables")
    plots = write_classification_plots(results, Path(out_dir) / "tables")
    text = format_tables(tables)
    if echo:
        shown = "".join(f"\n(plot: {p})" for p in plots)
        print("\n" + text + f"\n(tables written to {paths[0].parent})" + shown, flush=True)
    return text
