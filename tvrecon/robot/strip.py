"""Figures of a pick-and-place run: an animated GIF, an MP4 video and a PNG strip like the paper's robot figure.

Both read the run's log dict (``pick_place_log.npz``): scene frames (K,Hs,Ws,3) uint8 on top, each finger's tactile
image below (normal displacement channel, one colour scale for the whole run), frames without contact framed red,
frames with contact framed green.
"""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v2 as imageio
import matplotlib

from tvrecon.utils.atomic import atomic_open, atomic_savefig
from tvrecon.utils.shape_check import check_shape

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image, ImageDraw  # noqa: E402

__all__ = ["tactile_to_rgb", "key_frames", "compose_frame", "write_gif", "write_mp4", "write_strip"]

GREEN = (40, 200, 70)
RED = (220, 40, 40)


def tactile_to_rgb(image: np.ndarray, vmax: float, size: int = 120) -> np.ndarray:
    """Colour-map a tactile image's normal channel.

    Args:
        image: (3,H,W) float tactile image (x shear, y shear, z normal) in grid cells.
        vmax: displacement mapped to the top of the colour map (> 0).
        size: output side in pixels.

    Returns:
        (size,size,3) uint8 RGB.
    """
    img = np.asarray(image)
    check_shape(img, "(3, H, W)", "tactile image")
    z = np.clip(img[2] / max(vmax, 1e-9), 0.0, 1.0)
    rgb = (plt.get_cmap("inferno")(z)[..., :3] * 255).astype(np.uint8)
    return np.asarray(Image.fromarray(rgb).resize((size, size), Image.BILINEAR))


def _border(img: np.ndarray, color: tuple[int, int, int], width: int = 4) -> np.ndarray:
    out = img.copy()
    out[:width], out[-width:], out[:, :width], out[:, -width:] = color, color, color, color
    return out


def _vmax(log: dict) -> float:
    t = np.asarray(log["tactile"])
    return float(max(np.percentile(t[:, :, 2], 99.9), 1e-6)) if t.size else 1.0


def key_frames(log: dict) -> list[int]:
    """One frame index per phase present in the log: the last frame of that phase (the run's final frame for
    the release phase, when the pad is back at rest)."""
    phases = np.asarray(log["phase"])
    idx = []
    for ph in range(len(log["phase_names"])):
        where = np.flatnonzero(phases == ph)
        if len(where):
            idx.append(int(where[-1]))
    return idx


def compose_frame(log: dict, k: int, vmax: float | None = None, tactile_size: int = 0) -> np.ndarray:
    """One GIF frame: the scene on the left, the left/right finger tactile images stacked on the right.

    Returns:
        (Hs, Ws + Hs // 2, 3) uint8.
    """
    frame = np.asarray(log["frames"][k])
    Hs = frame.shape[0]
    ts = tactile_size or Hs // 2
    vmax = vmax if vmax is not None else _vmax(log)
    tiles = []
    for f in range(2):
        t = tactile_to_rgb(log["tactile"][k, f], vmax, ts)
        tiles.append(_border(t, GREEN if bool(log["contact"][k, f]) else RED))
    right = np.concatenate(tiles, axis=0)[:Hs]
    right = np.pad(right, ((0, Hs - right.shape[0]), (0, 0), (0, 0)))  # odd scene heights: a black row below
    out = np.concatenate([frame, right], axis=1)
    im = Image.fromarray(out)
    d = ImageDraw.Draw(im)
    names = [str(n) for n in log["phase_names"]]
    d.text((6, 4), f"{names[int(log['phase'][k])]}  t={float(log['time'][k]):.2f}s", fill=(0, 0, 0))
    d.text((frame.shape[1] + 6, 4), f"L {float(log['force'][k, 0]):.1f}N", fill=(255, 255, 255))
    d.text((frame.shape[1] + 6, ts + 4), f"R {float(log['force'][k, 1]):.1f}N", fill=(255, 255, 255))
    return np.asarray(im)


def _compose_all(log: dict, every: int) -> list[np.ndarray]:
    if len(log["frames"]) == 0:
        raise ValueError("the log holds no frames: nothing to animate")
    vmax = _vmax(log)
    return [compose_frame(log, k, vmax) for k in range(0, len(log["frames"]), every)]


def write_gif(log: dict, path: str | Path, fps: int = 15, every: int = 1) -> Path:
    """Write the run as an animated GIF (atomic). Returns the path."""
    path = Path(path)
    frames = _compose_all(log, every)
    with atomic_open(path, "wb") as fh:
        imageio.mimsave(fh, frames, format="GIF", duration=1.0 / fps, loop=0)
    return path


def write_mp4(log: dict, path: str | Path, fps: int = 15, every: int = 1) -> Path:
    """Write the run as an H.264 MP4 (atomic: a temporary file next to ``path``, renamed when complete).

    Needs the ``imageio-ffmpeg`` package (in the ``[robot]`` extra), which ships its own ffmpeg binary.

    Raises:
        ImportError: imageio-ffmpeg is not installed (the message says how to install it).
        ValueError: the log holds no frames.
    """
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError as err:
        raise ImportError(
            "MP4 output needs imageio-ffmpeg: pip install imageio-ffmpeg (or the [robot] extra); "
            "the GIF and the strip do not need it"
        ) from err
    path = Path(path)
    frames = _compose_all(log, every)
    h, w = frames[0].shape[:2]
    # H.264 with yuv420p needs even sizes: pad by one black row/column where needed instead of resampling
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        with imageio.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264", macro_block_size=1) as writer:
            for frame in frames:
                writer.append_data(np.pad(frame, pad))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_strip(log: dict, path: str | Path, frames: list[int] | None = None) -> Path:
    """Write the paper-style strip (atomic): one column per phase, scene on top, left/right tactile below.

    Returns:
        The PNG path.
    """
    path = Path(path)
    idx = frames if frames is not None else key_frames(log)
    if not idx:
        raise ValueError("the log holds no frames: nothing to draw")
    vmax = _vmax(log)
    names = [str(n) for n in log["phase_names"]]
    n = len(idx)
    fig, axes = plt.subplots(
        3, n, figsize=(2.3 * n, 5.6), gridspec_kw={"height_ratios": [1.0, 1.05, 1.05]}, squeeze=False
    )
    for c, k in enumerate(idx):
        ax = axes[0, c]
        ax.imshow(np.asarray(log["frames"][k]))
        ax.set_title(names[int(log["phase"][k])], fontsize=10)
        for r, label in ((1, "left"), (2, "right")):
            contact = bool(log["contact"][k, r - 1])
            tile = _border(tactile_to_rgb(log["tactile"][k, r - 1], vmax, 96), GREEN if contact else RED, 5)
            ax = axes[r, c]
            ax.imshow(tile)
            ax.set_xlabel(f"{float(log['force'][k, r - 1]):.1f} N" if contact else "no contact", fontsize=8)
            if c == 0:
                ax.set_ylabel(f"{label} finger", fontsize=9)
        for r in range(3):
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
    status = "success" if bool(log.get("success", True)) else "FAILED"
    fig.suptitle(
        f"{str(log.get('object', ''))}: {status} ({str(log.get('message', ''))}); tactile = normal "
        f"displacement (0..{vmax:.2f} cells), green = contact, red = none",
        fontsize=9,
    )
    fig.tight_layout()
    atomic_savefig(fig, path, format="png", dpi=110)
    plt.close(fig)
    return path
