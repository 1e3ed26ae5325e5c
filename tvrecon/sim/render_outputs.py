"""Pictures of the sensor outputs beyond displacement: force field, markers, RGB (see ``forces``, ``markers``,
``photometric``). Each is drawn in the orientation of ``tactile.png`` (sensor x right, y up); writes are atomic.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image
from torch import Tensor

from tvrecon.atomic import atomic_write_bytes
from tvrecon.sim.render import _colorbar_png, _draw_tactile, _save_figure

__all__ = ["auto_arrow_gain", "save_force_png", "save_markers_png", "save_rgb_png", "save_outputs_png"]


def _np(x: Tensor | np.ndarray) -> np.ndarray:
    arr = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    if not np.isfinite(arr).all():
        raise ValueError("cannot draw NaN or infinite values")
    return arr.astype(np.float32)


def _draw_force(ax, field: np.ndarray):
    if field.ndim != 3 or field.shape[-1] != 3:
        raise ValueError(f"force field must have shape (H, W, 3), got {field.shape}")
    img = field.transpose(2, 0, 1)
    return _draw_tactile(ax, img, max(float(img[2].max()), 1e-12), arrows=True, cmap="magma")


def auto_arrow_gain(displacement: np.ndarray, spacing: float) -> float:
    """Arrow length per taxel of displacement so that the longest arrow is 0.8 marker spacings (>= 1)."""
    top = float(np.hypot(displacement[:, 0], displacement[:, 1]).max()) if len(displacement) else 0.0
    return max(1.0, 0.8 * float(spacing) / top) if top > 1e-9 else 1.0


def _draw_markers(ax, dots: np.ndarray, rest: np.ndarray, disp: np.ndarray, pixels_per_taxel: int, arrow_gain: float):
    if dots.ndim != 2 or rest.shape != disp.shape or rest.ndim != 2 or rest.shape[1] != 2:
        raise ValueError(f"expected dots (h, w) and rest, disp (M, 2), got {dots.shape}, {rest.shape}, {disp.shape}")
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
    if a.ndim != 3 or a.shape[0] != 3:
        raise ValueError(f"rgb must have shape (3, H, W), got {a.shape}")
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
