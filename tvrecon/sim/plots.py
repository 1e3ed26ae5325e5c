"""Pictures of tactile readings and pad particles (object views live in :mod:`tvrecon.data.views`).

- :func:`save_tactile_png`: normal displacement as a colormap with shear arrows and a colorbar.
- :func:`save_sequence_png`: the deformation over time, tactile images side by side with a cross-section of the pad.
- :func:`save_ply`: pad particles as a coloured point cloud.
- :func:`save_force_png`, :func:`save_markers_png`, :func:`save_rgb_png`, :func:`save_outputs_png`: the sensor
  outputs beyond displacement (force field, markers, RGB; :mod:`tvrecon.sim.sensor.elastic_pad`), in the orientation of
  ``tactile.png`` (sensor x right, y up).

All writes are atomic (temporary file in the same directory, then ``os.replace``).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from PIL import Image
from torch import Tensor

from tvrecon.utils.atomic import atomic_write_bytes
from tvrecon.utils.shape_check import check_shape


def _save_figure(fig: Figure, path: str | Path, dpi: int) -> Path:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return atomic_write_bytes(path, buf.getvalue())


def _colorbar_png(
    draw: Callable[[Any], Any], path: str | Path, dpi: int, colorbar: str, xlabel: str, title: str
) -> Path:
    """One sensor-frame panel with a colorbar: ``draw(ax)`` draws it and returns the image the colorbar shows."""
    fig = Figure(figsize=(5.2, 4.4))
    ax = fig.add_subplot(1, 1, 1)
    im = draw(ax)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04).set_label(colorbar)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("sensor y")
    ax.set_title(title)
    return _save_figure(fig, path, dpi)


def _as_image(image: Tensor | np.ndarray) -> np.ndarray:
    img = image.detach().cpu().numpy() if isinstance(image, Tensor) else np.asarray(image)
    check_shape(img, "(3, H, W)", "tactile image")
    if not np.isfinite(img).all():
        raise ValueError("tactile image contains NaN or infinite values")
    return img.astype(np.float32)


def _draw_tactile(
    ax, img: np.ndarray, vmax: float, arrows: bool, cmap: str = "inferno", shear_max: float | None = None
):
    """Draw normal displacement (colour) and shear (arrows, scaled by ``shear_max``) of one (3, H, W) image."""
    H, W = img.shape[1:]
    im = ax.imshow(img[2], cmap=cmap, vmin=0.0, vmax=vmax, origin="lower", interpolation="bilinear")
    if arrows:
        k = max(1, min(H, W) // 12)
        ys, xs = np.mgrid[k // 2 : H : k, k // 2 : W : k]
        u, v = img[0][ys, xs], img[1][ys, xs]
        top = float(shear_max) if shear_max is not None else float(np.hypot(u, v).max())
        if top > 1e-6:
            ax.quiver(xs, ys, u, v, color="cyan", angles="xy", scale_units="xy", scale=top / (1.6 * k), width=0.006)
    ax.set_xticks([])
    ax.set_yticks([])
    return im


def save_tactile_png(
    image: Tensor | np.ndarray, path: str | Path, title: str | None = None, vmax: float | None = None, dpi: int = 110
) -> Path:
    """Tactile image as a PNG: normal displacement colormap, shear arrows, colorbar in grid cells.

    Args:
        image: (3, H, W) float32 displacement in cells, channels (x shear, y shear, z normal).
        path: output .png path. title: optional title. vmax: colour scale top (default: the image max).
    Returns:
        the written path.
    """
    img = _as_image(image)
    top = float(vmax) if vmax is not None else max(float(img[2].max()), 1e-3)
    shear = float(np.hypot(img[0], img[1]).max())
    xlabel = f"sensor x   (arrows: shear, max {shear:.3f} cells)"
    title = title or f"tactile image {img.shape[1]}x{img.shape[2]}, max normal {float(img[2].max()):.3f} cells"
    colorbar = "normal displacement into the pad (cells)"
    return _colorbar_png(lambda ax: _draw_tactile(ax, img, top, arrows=True), path, dpi, colorbar, xlabel, title)


def save_sequence_png(
    frames: Tensor | np.ndarray,
    path: str | Path,
    steps: Sequence[int] | None = None,
    sections: Sequence[np.ndarray] | None = None,
    dpi: int = 100,
) -> Path:
    """The deformation over time: K tactile images side by side (shared colour scale), over pad cross-sections.

    Args:
        frames: (K, 3, H, W) float32 tactile images in cells.
        path: output .png path.
        steps: K step indices for the titles.
        sections: K arrays (N_k, 3) of pad particles in the sensor frame (x, y, z), e.g. the middle particle row
            of ``reading.particles`` mapped back with the frame; drawn as x-z scatter (z up = towards the hand,
            z = 0 the object's first contact point, dashed).
    Returns:
        the written path.
    """
    arr = frames.detach().cpu().numpy() if isinstance(frames, Tensor) else np.asarray(frames)
    check_shape(arr, "(K, 3, H, W)", "frames")
    if arr.shape[0] < 1:
        raise ValueError(f"frames must have shape (K, 3, H, W) with K >= 1, got {tuple(arr.shape)}")
    K = arr.shape[0]
    if steps is not None and len(steps) != K:
        raise ValueError(f"steps must have K={K} entries, got {len(steps)}")
    if sections is not None and len(sections) != K:
        raise ValueError(f"sections must have K={K} entries, got {len(sections)}")
    top = max(float(arr[:, 2].max()), 1e-3)
    shear_max = float(np.hypot(arr[:, 0], arr[:, 1]).max())
    rows = 2 if sections is not None else 1
    fig = Figure(figsize=(2.6 * K + 1.0, 2.7 * rows))
    axes = fig.subplots(rows, K, squeeze=False)
    im = None
    for k in range(K):
        img = _as_image(arr[k])
        im = _draw_tactile(axes[0, k], img, top, arrows=True, shear_max=shear_max)
        label = f"step {steps[k]}" if steps is not None else f"frame {k}"
        axes[0, k].set_title(f"{label}\nmax {float(img[2].max()):.2f} cells", fontsize=9)
    if sections is not None:
        all_z = np.concatenate([np.asarray(sec)[:, 2] for sec in sections] + [np.zeros(1)])
        zlo, zhi = float(all_z.min()), float(all_z.max())
        for k, sec in enumerate(sections):
            sec = np.asarray(sec)
            ax = axes[1, k]
            pts = sec
            ax.axhline(0.0, color="0.6", lw=0.8, ls="--")  # the first point of the object the pad meets
            ax.scatter(pts[:, 0], pts[:, 2], s=4, c=pts[:, 2], cmap="viridis", vmin=zlo, vmax=zhi)
            ax.set_ylim(zlo - 0.05 * (zhi - zlo + 1e-9), zhi + 0.05 * (zhi - zlo + 1e-9))
            ax.set_aspect("auto")
            ax.set_xticks([])
            ax.tick_params(labelsize=7)
            ax.set_title("pad cross-section (x-z, cells)", fontsize=8)
    assert im is not None
    cb = fig.colorbar(im, ax=list(axes[0]), fraction=0.02, pad=0.01)
    cb.set_label("normal (cells)", fontsize=8)
    return _save_figure(fig, path, dpi)


def save_ply(points: Tensor | np.ndarray, path: str | Path, values: Tensor | np.ndarray | None = None) -> Path:
    """Pad particles as a PLY point cloud, coloured by ``values`` (viridis) when given.

    Args:
        points: (P, 3) float32 positions. values: (P,) float32 scalars for colour (e.g. displacement), or None.
    Returns:
        the written path.
    """
    pts = points.detach().cpu().numpy() if isinstance(points, Tensor) else np.asarray(points)
    check_shape(pts, "(P, 3)", "points")
    if len(pts) == 0:
        raise ValueError(f"points must have shape (P, 3) with P > 0, got {tuple(pts.shape)}")
    colors = None
    if values is not None:
        val = values.detach().cpu().numpy() if isinstance(values, Tensor) else np.asarray(values)
        if val.shape != (len(pts),):
            raise ValueError(f"values must have shape (P,) = ({len(pts)},), got {tuple(val.shape)}")
        lo, hi = float(val.min()), float(val.max())
        rgba = colormaps["viridis"](Normalize(lo, hi if hi > lo else lo + 1.0)(val))
        colors = (rgba * 255).astype(np.uint8)
    data = trimesh.PointCloud(pts.astype(np.float64), colors=colors).export(file_type="ply")
    return atomic_write_bytes(path, data if isinstance(data, bytes) else data.encode())


def to_numpy(x: Tensor | np.ndarray) -> np.ndarray:
    """Detach a tensor to numpy (helper for callers that mix both)."""
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def _np(x: Tensor | np.ndarray) -> np.ndarray:
    arr = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    if not np.isfinite(arr).all():
        raise ValueError("cannot draw NaN or infinite values")
    return arr.astype(np.float32)


def _draw_force(ax, field: np.ndarray):
    check_shape(field, "(H, W, 3)", "force field")
    img = field.transpose(2, 0, 1)
    return _draw_tactile(ax, img, max(float(img[2].max()), 1e-12), arrows=True, cmap="magma")


def auto_arrow_gain(displacement: np.ndarray, spacing: float) -> float:
    """Arrow length per taxel of displacement so that the longest arrow is 0.8 marker spacings (>= 1)."""
    top = float(np.hypot(displacement[:, 0], displacement[:, 1]).max()) if len(displacement) else 0.0
    return max(1.0, 0.8 * float(spacing) / top) if top > 1e-9 else 1.0


def _draw_markers(ax, dots: np.ndarray, rest: np.ndarray, disp: np.ndarray, pixels_per_taxel: int, arrow_gain: float):
    check_shape(dots, "(h, w)", "dots")
    check_shape(rest, "(M, 2)", "rest")
    if disp.shape != rest.shape:
        raise ValueError(f"disp must have the shape of rest {rest.shape}, got {disp.shape}")
    k = float(pixels_per_taxel)
    ax.imshow(1.0 - 0.85 * dots, cmap="gray", vmin=0, vmax=1, origin="lower", interpolation="bilinear")
    px = (rest + 0.5) * k - 0.5  # taxel -> output pixel coordinates
    ax.quiver(px[:, 0], px[:, 1], disp[:, 0] * k * arrow_gain, disp[:, 1] * k * arrow_gain, color="tab:red",
              angles="xy", scale_units="xy", scale=1.0, width=0.006)  # fmt: skip
    ax.set_xticks([])
    ax.set_yticks([])


def save_force_png(field: Tensor | np.ndarray, path: str | Path, title: str | None = None, dpi: int = 110) -> Path:
    """Per-taxel force field: normal force colormap with shear arrows.

    Args:
        field: (H, W, 3) force per taxel in the sensor frame (``TactileReading.force_field``).
    """
    f = _np(field)
    xlabel = f"sensor x   (arrows: shear, total {np.hypot(f[..., 0].sum(), f[..., 1].sum()):.3g})"
    title = title or f"force field, total normal {float(f[..., 2].sum()):.4g}"
    colorbar = "normal force per taxel (sim. units)"
    return _colorbar_png(lambda ax: _draw_force(ax, f), path, dpi, colorbar, xlabel, title)


def save_markers_png(
    dots: Tensor | np.ndarray,
    rest: Tensor | np.ndarray,
    displacement: Tensor | np.ndarray,
    path: str | Path,
    pixels_per_taxel: int,
    arrow_gain: float = 1.0,
    title: str | None = None,
    dpi: int = 110,
) -> Path:
    """Marker image (dark dots on the gel) with each marker's displacement as an arrow from its rest position.

    Args:
        dots: (H * k, W * k) coverage from ``markers.render_markers``. rest, displacement: (M, 2) taxels.
        pixels_per_taxel: the k of ``dots``. arrow_gain: arrow length per taxel of displacement.
    """
    d, r, u = _np(dots), _np(rest), _np(displacement)
    fig = Figure(figsize=(4.8, 4.6))
    ax = fig.add_subplot(1, 1, 1)
    _draw_markers(ax, d, r, u, pixels_per_taxel, arrow_gain)
    top = float(np.hypot(u[:, 0], u[:, 1]).max()) if len(u) else 0.0
    ax.set_title(title or f"markers: {len(r)} dots, max displacement {top:.3g} taxels (arrows x{arrow_gain:.3g})")
    return _save_figure(fig, path, dpi)


def save_rgb_png(rgb: Tensor | np.ndarray, path: str | Path, upscale: int = 4) -> Path:
    """(3, H, W) RGB in [0, 1] as a plain PNG, row 0 at the bottom (y up), scaled up ``upscale`` times."""
    a = _np(rgb)
    check_shape(a, "(3, H, W)", "rgb")
    pix = (np.clip(a.transpose(1, 2, 0)[::-1], 0, 1) * 255 + 0.5).astype(np.uint8)
    im = Image.fromarray(np.ascontiguousarray(pix))
    if int(upscale) > 1:
        im = im.resize((im.width * int(upscale), im.height * int(upscale)), Image.Resampling.BILINEAR)
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True)
    return atomic_write_bytes(path, buf.getvalue())


def save_outputs_png(
    path: str | Path,
    image: Tensor | np.ndarray,
    field: Tensor | np.ndarray | None = None,
    markers: tuple | None = None,
    arrow_gain: float = 1.0,
    rgb: Tensor | np.ndarray | None = None,
    dpi: int = 90,
) -> Path:
    """One row of panels: the displacement image and whichever outputs are given.

    Args:
        image: (3, H, W) displacement (cells). field: (H, W, 3) force field.
        markers: (dots, rest, displacement, pixels_per_taxel) as for :func:`save_markers_png`; arrows are drawn
            ``arrow_gain`` times their length. rgb: (3, H, W) in [0, 1].
    """
    img = _np(image)
    panels = 1 + sum(x is not None for x in (field, markers, rgb))
    fig = Figure(figsize=(2.9 * panels, 3.1))
    axes = fig.subplots(1, panels, squeeze=False)[0]
    _draw_tactile(axes[0], img, max(float(img[2].max()), 1e-3), arrows=True)
    axes[0].set_title("displacement (normal, shear)", fontsize=9)
    k = 1
    if field is not None:
        _draw_force(axes[k], _np(field))
        axes[k].set_title("force per taxel (normal, shear)", fontsize=9)
        k += 1
    if markers is not None:
        dots, rest, disp, ppt = markers
        _draw_markers(axes[k], _np(dots), _np(rest), _np(disp), int(ppt), arrow_gain)
        axes[k].set_title(f"markers (arrows: displacement x{arrow_gain:.2g})", fontsize=9)
        k += 1
    if rgb is not None:
        a = _np(rgb)
        axes[k].imshow(np.clip(a.transpose(1, 2, 0), 0, 1), origin="lower", interpolation="bilinear")
        axes[k].set_xticks([])
        axes[k].set_yticks([])
        axes[k].set_title("RGB (photometric)", fontsize=9)
    return _save_figure(fig, path, dpi)
