"""Figures of a reconstruction test: predicted vs ground-truth meshes side by side (:func:`render_mesh_comparison`)
and meshes written as OBJ (:func:`export_obj`). Rendered with matplotlib's Agg backend (headless); writes are atomic."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from tvrecon.utils.atomic import atomic_write_text, save_and_close  # noqa: E402
from tvrecon.utils.shape_check import check_shape

__all__ = ["export_obj", "render_mesh_comparison"]


def _np(x: torch.Tensor | np.ndarray) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        return x.detach().float().cpu().numpy()
    return np.asarray(x, dtype=np.float32)


def _check_points(name: str, x: np.ndarray) -> None:
    check_shape(x, "(N, 3)", name)
    if x.shape[0] == 0:
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
    check_shape(faces, "(F, 3)", "pred_faces")
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise ValueError(f"pred_faces index outside [0, {len(verts)}): min {faces.min()}, max {faces.max()}")
    both3d = np.concatenate([verts, gt])
    centre = (both3d.max(0) + both3d.min(0)) / 2
    n_cols = 3 if image is not None else 2
    fig, axes = plt.subplots(2, n_cols, figsize=(3.2 * n_cols, 6.4), squeeze=False)
    col = 0
    if image is not None:
        img = _np(image)
        check_shape(img, "(3, H, W)", "image")
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
    check_shape(f, "(F, 3)", "faces")
    path = Path(path)
    if path.suffix != ".obj":
        raise ValueError(f"export_obj writes .obj files, got path {path}")
    return atomic_write_text(path, trimesh.exchange.obj.export_obj(trimesh.Trimesh(v, f, process=False)))
