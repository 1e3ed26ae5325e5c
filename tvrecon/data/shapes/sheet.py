"""Contact sheet: a labelled grid of ray-cast renders of every class (a few instances each)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw
from tqdm import tqdm

from tvrecon.utils.atomic import atomic_open

log = logging.getLogger(__name__)


def render_mesh(mesh: trimesh.Trimesh, size: int = 128, view: Sequence[float] = (1.0, -1.4, 1.1)) -> np.ndarray:
    """Orthographic Lambert render of a unit-box mesh seen from direction ``view`` (3,); returns (H,W,3) uint8."""
    d = -np.asarray(view, dtype=float)
    d /= np.linalg.norm(d)
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(d, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    half = 0.5 * np.sqrt(3.0) * float(np.max(np.abs(mesh.bounds)) * 2.0)
    s = np.linspace(-half, half, size)
    u, v = np.meshgrid(s, -s)  # image rows go down
    origins = (u[..., None] * right + v[..., None] * up).reshape(-1, 3) - 3.0 * d
    dirs = np.broadcast_to(d, origins.shape).copy()
    tri = mesh.ray.intersects_first(origins, dirs)
    img = np.full((size * size, 3), 255.0)
    hit = tri >= 0
    if hit.any():
        n = mesh.face_normals[tri[hit]]
        light = -d + 0.6 * up + 0.4 * right
        light /= np.linalg.norm(light)
        shade = 0.25 + 0.75 * np.abs(n @ light)
        color = np.array([90.0, 140.0, 210.0])
        img[hit] = shade[:, None] * color[None, :] + 20.0
    return np.clip(img, 0, 255).astype(np.uint8).reshape(size, size, 3)


def contact_sheet(
    build: Callable[[str, int], trimesh.Trimesh],
    classes: Sequence[str],
    out: str | Path,
    instances: int = 3,
    size: int = 128,
    columns: int = 5,
) -> Path:
    """Render ``instances`` meshes ``build(cls, i)`` per class into one labelled PNG at ``out`` (atomic write)."""
    if instances < 1 or size < 16 or columns < 1:
        raise ValueError(f"need instances >= 1, size >= 16, columns >= 1; got {instances}, {size}, {columns}")
    label_h = 18
    cell_w, cell_h = instances * size, size + label_h
    rows = (len(classes) + columns - 1) // columns
    sheet = Image.new("RGB", (columns * cell_w, rows * cell_h), "white")
    draw = ImageDraw.Draw(sheet)
    jobs = [(k, c, i) for k, c in enumerate(classes) for i in range(instances)]
    for k, cls, i in tqdm(jobs, desc="contact sheet", unit="mesh"):
        x0, y0 = (k % columns) * cell_w, (k // columns) * cell_h
        try:
            tile = Image.fromarray(render_mesh(build(cls, i), size))
        except Exception as err:  # show the failure in the sheet instead of aborting the whole figure
            log.warning("contact sheet: %s instance %d failed: %s", cls, i, err)
            tile = Image.new("RGB", (size, size), (255, 200, 200))
            ImageDraw.Draw(tile).text((4, size // 2), f"error: {type(err).__name__}", fill="black")
        sheet.paste(tile, (x0 + i * size, y0 + label_h))
        if i == 0:
            draw.text((x0 + 4, y0 + 3), f"{k}: {cls}", fill="black")
            draw.rectangle([x0, y0, x0 + cell_w - 1, y0 + cell_h - 1], outline=(200, 200, 200))
    with atomic_open(out, "wb") as fh:
        sheet.save(fh, format="PNG")
    return Path(out)
