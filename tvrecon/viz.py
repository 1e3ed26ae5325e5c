"""Figures for training and evaluation: predicted vs ground-truth meshes side by side, loss curves, mesh export.

Compare runs (one panel per metric, one line per run) from the command line::

    python -m tvrecon.viz compare visual=runs/small/visual_only full=runs/small/full --out compare.png

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
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from tvrecon.atomic import atomic_savefig, atomic_write_text  # noqa: E402


def save_and_close(fig: plt.Figure, path: str | Path, dpi: int = 100) -> Path:
    """Save ``fig`` atomically and close it (pyplot keeps every open figure alive)."""
    try:
        return atomic_savefig(fig, path, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)


def _np(x: torch.Tensor | np.ndarray) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().float().cpu().numpy()
    return np.asarray(x, dtype=np.float32)


def _check_points(name: str, x: np.ndarray) -> None:
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] == 0:
        raise ValueError(f"{name} must have shape (N, 3) with N > 0, got {tuple(x.shape)}")
    if not np.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf values")


def _project(points: np.ndarray, view: str, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame points -> 2D plot coordinates, depth (larger = farther) and the viewing direction.

    ``front``: the camera's own perspective view (u = x / z, v = -y / z, as in the input image).
    ``side``: orthographic view from the +x side of the object's centre (shows the depth the front view hides).
    """
    if view == "front":
        z = np.clip(points[:, 2], 1e-6, None)
        return np.stack([points[:, 0] / z, -points[:, 1] / z], 1), points[:, 2], np.array([0.0, 0.0, 1.0])
    q = points - centre
    return np.stack([q[:, 2], -q[:, 1]], 1), -q[:, 0], np.array([-1.0, 0.0, 0.0])


def _draw_mesh(ax: plt.Axes, verts: np.ndarray, faces: np.ndarray, view: str, centre: np.ndarray) -> None:
    """Painter's algorithm with Lambert shading: one 2D PolyCollection (much faster than mplot3d)."""
    uv, depth, direction = _project(verts, view, centre)
    tri = verts[faces]  # (F, 3, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    shade = 0.25 + 0.75 * np.abs(normals @ direction)
    order = np.argsort(-depth[faces].mean(1))  # far faces first
    colors = np.clip(shade[order, None] * np.array([[0.55, 0.7, 0.95]]), 0, 1)
    ax.add_collection(PolyCollection(uv[faces[order]], facecolors=colors, edgecolors="none"))


def _draw_points(ax: plt.Axes, points: np.ndarray, view: str, centre: np.ndarray) -> None:
    uv, depth, _ = _project(points, view, centre)
    order = np.argsort(-depth)
    ax.scatter(uv[order, 0], uv[order, 1], s=2, c=depth[order], cmap="viridis_r")


def render_mesh_comparison(
    pred_verts: torch.Tensor | np.ndarray,
    pred_faces: torch.Tensor | np.ndarray,
    gt_points: torch.Tensor | np.ndarray,
    path: str | Path,
    title: str = "",
    image: torch.Tensor | np.ndarray | None = None,
) -> Path:
    """Save a PNG with the predicted mesh and the ground-truth surface points side by side.

    Two rows with shared axes per row: the camera's own view (as in the input image) and a side view from +x.

    Args:
        pred_verts: (V, 3) float predicted vertices (camera frame, z > 0 in front of the camera).
        pred_faces: (F, 3) int64 triangle indices into ``pred_verts``.
        gt_points: (N, 3) float ground-truth surface points, same frame as ``pred_verts``.
        path: output ``.png`` path (parent folders are created).
        title: figure title.
        image: optional (3, H, W) float [0, 1] input view shown in a first column.
    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    verts, faces, gt = _np(pred_verts), np.asarray(_np(pred_faces), dtype=np.int64), _np(gt_points)
    _check_points("pred_verts", verts)
    _check_points("gt_points", gt)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"pred_faces must have shape (F, 3), got {tuple(faces.shape)}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise ValueError(f"pred_faces index outside [0, {len(verts)}): min {faces.min()}, max {faces.max()}")
    both3d = np.concatenate([verts, gt])
    centre = (both3d.max(0) + both3d.min(0)) / 2
    n_cols = 3 if image is not None else 2
    fig, axes = plt.subplots(2, n_cols, figsize=(3.2 * n_cols, 6.4), squeeze=False)
    col = 0
    if image is not None:
        img = _np(image)
        if img.ndim != 3 or img.shape[0] != 3:
            raise ValueError(f"image must have shape (3, H, W), got {tuple(img.shape)}")
        axes[0, 0].imshow(np.clip(img.transpose(1, 2, 0), 0, 1))
        axes[0, 0].set_title("input view", fontsize=9)
        axes[0, 0].axis("off")
        axes[1, 0].axis("off")
        col = 1
    for row, view in enumerate(("front", "side")):
        ax_pred, ax_gt = axes[row, col], axes[row, col + 1]
        _draw_mesh(ax_pred, verts, faces, view, centre)
        _draw_points(ax_gt, gt, view, centre)
        both = np.concatenate([_project(verts, view, centre)[0], _project(gt, view, centre)[0]])
        lo, hi = both.min(0), both.max(0)
        mid, half = (lo + hi) / 2, (float((hi - lo).max()) / 2 or 1.0) * 1.05
        for ax in (ax_pred, ax_gt):
            ax.set_xlim(mid[0] - half, mid[0] + half)
            ax.set_ylim(mid[1] - half, mid[1] + half)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
        ax_pred.set_title(f"prediction, {view} ({len(verts)} verts)", fontsize=9)
        ax_gt.set_title(f"ground truth, {view} ({len(gt)} pts)", fontsize=9)
    if title:
        fig.suptitle(title)
    return save_and_close(fig, path)


def export_obj(verts: torch.Tensor | np.ndarray, faces: torch.Tensor | np.ndarray, path: str | Path) -> Path:
    """Write a triangle mesh as Wavefront ``.obj`` (atomically) with trimesh.

    Args:
        verts: (V, 3) float vertices.
        faces: (F, 3) int64 triangle indices.
        path: output path ending in ``.obj``.
    """
    v, f = _np(verts), np.asarray(_np(faces), dtype=np.int64)
    _check_points("verts", v)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {tuple(f.shape)}")
    path = Path(path)
    if path.suffix != ".obj":
        raise ValueError(f"export_obj writes .obj files, got path {path}")
    return atomic_write_text(path, trimesh.exchange.obj.export_obj(trimesh.Trimesh(v, f, process=False)))


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
    """``python -m tvrecon.viz compare LABEL=RUN ... --out PNG [--keys val/chamfer train/loss]``."""
    ap = argparse.ArgumentParser(prog="python -m tvrecon.viz", description="Figures of training runs.")
    sub = ap.add_subparsers(dest="command", required=True)
    cmp = sub.add_parser("compare", help="overlay logged metrics of several runs (one line per run)")
    cmp.add_argument("runs", nargs="+", help="LABEL=RUN_DIR (a train.py run folder) or LABEL=metrics.csv")
    cmp.add_argument("--out", required=True, help="output PNG")
    cmp.add_argument("--keys", nargs="+", default=["val/chamfer", "train/loss"], help="logged columns to plot")
    args = ap.parse_args(argv)
    runs: dict[str, str] = {}
    for item in args.runs:
        label, sep, run = item.partition("=")
        if not sep or not label or not run:
            ap.error(f"runs are LABEL=RUN_DIR, got {item!r}")
        runs[label] = run
    try:
        out = plot_run_comparison(runs, args.out, args.keys)
    except ValueError as err:
        ap.error(str(err))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
