"""Figures of training runs: loss curves of one run, runs compared (mesh renders of a test:
:mod:`tvrecon.models.mesh_figures`).

Compare runs (one panel per metric, one line per run) from the command line::

    python -m tvrecon.report.viz compare visual=runs/small/visual_only full=runs/small/full [--out compare.png]

Without ``--out`` the figure goes to ``outputs/compare/<time>/compare.png``, like every command of the project.

Everything renders with matplotlib's Agg backend (headless) and writes atomically (temporary file in the
target folder, then ``os.replace``).
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from tvrecon.utils.atomic import save_and_close  # noqa: E402
from tvrecon.utils.output_dir import announce, default_output_dir  # noqa: E402


def read_metrics_csv(path: str | Path) -> dict[str, list[tuple[float, float]]]:
    """Read a Lightning ``CSVLogger`` ``metrics.csv`` into ``{column: [(step, value), ...]}`` (empty cells skipped)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"metrics file {path} does not exist (is the CSV logger enabled? logger=default or csv)")
    series: dict[str, list[tuple[float, float]]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            step = float(row.get("step") or 0)
            for key, val in row.items():
                if key in ("step", "epoch") or val in (None, ""):
                    continue
                try:
                    series.setdefault(key, []).append((step, float(val)))
                except ValueError:
                    continue
    return series


def plot_loss_curves(metrics_csv: str | Path, path: str | Path, keys: Sequence[str] | None = None) -> Path:
    """Plot the logged losses and metrics of a run (one panel per metric family) to a PNG.

    Args:
        metrics_csv: the CSV logger's ``metrics.csv``.
        path: output ``.png``.
        keys: columns to plot; default every ``train/*`` and ``val/*`` column except learning rates.
    """
    series = read_metrics_csv(metrics_csv)
    if keys is None:
        keys = sorted(k for k in series if k.startswith(("train/", "val/")) and not k.startswith("lr"))
    keys = [k for k in keys if k in series and series[k]]
    if not keys:
        raise ValueError(f"no train/* or val/* values found in {metrics_csv}; columns: {sorted(series)}")
    # one panel per column, except train/loss and val/loss (same quantity) which share one; val/chamfer is the
    # x1e-3 metric, not the training chamfer loss, so it gets its own panel
    groups: dict[str, list[str]] = {}
    for k in keys:
        groups.setdefault("loss" if k.split("/", 1)[-1] == "loss" else k, []).append(k)
    n = len(groups)
    ncols = min(4, n)
    nrows = math.ceil(n / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4 * ncols, 3 * nrows), squeeze=False)
    for ax, (name, members) in zip(axes.flat, groups.items()):
        for k in members:
            steps, vals = zip(*series[k])
            ax.plot(steps, vals, marker="." if len(vals) < 30 else None, label=k)
        ax.set_title(name)
        ax.set_xlabel("step")
        if all(v > 0 for k in members for _, v in series[k]):
            ax.set_yscale("log")
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    return save_and_close(fig, path)


def find_metrics_csv(run: str | Path) -> Path:
    """The CSV logger file of a run: ``run`` itself if it is a file, else ``<run>/csv/metrics.csv`` or the only
    ``metrics.csv`` below ``run``."""
    run = Path(run)
    if run.is_file():
        return run
    if (run / "csv" / "metrics.csv").is_file():
        return run / "csv" / "metrics.csv"
    found = sorted(run.rglob("metrics.csv")) if run.is_dir() else []
    if len(found) != 1:
        what = "no" if not found else f"{len(found)}"
        raise ValueError(
            f"{what} metrics.csv below {run}: give a train.py run folder (it holds csv/metrics.csv) or the CSV itself"
        )
    return found[0]


def plot_run_comparison(
    runs: Mapping[str, str | Path], path: str | Path, keys: Sequence[str] = ("val/chamfer", "train/loss")
) -> Path:
    """Overlay the same logged metrics of several runs: one panel per metric, one line per run, against the step.

    Args:
        runs: label -> run folder or ``metrics.csv`` (see ``find_metrics_csv``).
        path: output ``.png``.
        keys: logged columns to plot; a column no run logged is an error, a run without it is left out of its panel.
    """
    if not runs:
        raise ValueError("runs is empty: give at least one label -> run folder")
    if not keys:
        raise ValueError("keys is empty: name at least one logged column, e.g. val/chamfer")
    series = {label: read_metrics_csv(find_metrics_csv(run)) for label, run in runs.items()}
    for k in keys:
        if not any(s.get(k) for s in series.values()):
            columns = sorted({c for s in series.values() for c in s})
            raise ValueError(f"no run logged {k!r}; columns: {columns}")
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 3.5), squeeze=False)
    for ax, k in zip(axes.flat, keys):
        for label, s in series.items():
            if s.get(k):
                steps, vals = zip(*s[k])
                ax.plot(steps, vals, marker="." if len(vals) < 40 else None, label=label)
        ax.set_title(k)
        ax.set_xlabel("step")
        if all(v > 0 for s in series.values() for _, v in s.get(k, [])):
            ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_and_close(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m tvrecon.report.viz compare LABEL=RUN ... [--out PNG] [--keys val/chamfer train/loss]``."""
    ap = argparse.ArgumentParser(prog="python -m tvrecon.report.viz", description="Figures of training runs.")
    sub = ap.add_subparsers(dest="command", required=True)
    cmp = sub.add_parser("compare", help="overlay logged metrics of several runs (one line per run)")
    cmp.add_argument("runs", nargs="+", help="LABEL=RUN_DIR (a train.py run folder) or LABEL=metrics.csv")
    cmp.add_argument("--out", default=None, help="output PNG (default outputs/compare/<time>/compare.png)")
    cmp.add_argument("--keys", nargs="+", default=["val/chamfer", "train/loss"], help="logged columns to plot")
    args = ap.parse_args(argv)
    runs: dict[str, str] = {}
    for item in args.runs:
        label, sep, run = item.partition("=")
        if not sep or not label or not run:
            ap.error(f"runs are LABEL=RUN_DIR, got {item!r}")
        runs[label] = run
    try:
        out = plot_run_comparison(runs, args.out or default_output_dir("compare") / "compare.png", args.keys)
    except ValueError as err:
        ap.error(str(err))
    print(f"wrote {out}")
    announce(out.parent)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
