"""Preview one reconstruction sample as a PNG: the view, its tactile images and the touches drawn on the view.

    python -m tvrecon.data.preview [--out preview.png --shape mug --touches 6 --seed 0 --pad 32]

The object comes from the procedural library (`make_shape`), the camera and touches from the same seeded
policies as the datasets (`sample_camera`, `sample_touches(visible_only=True)`), the tactile images from the EIP
simulator. Each touch is drawn on the view as its projected contact point (numbered) with an arrow showing the
press direction (projected from the contact point back along -direction: the way the pad comes in), and its
tactile image (normal displacement as a colour map, shear as arrows) carries the same colour and number.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: this module only writes files

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from tvrecon.data.touches.policies import ConeTouchPolicy, sample_touches, simulate_touches  # noqa: E402
from tvrecon.data.views import Camera, project_points, render_view, sample_camera  # noqa: E402
from tvrecon.utils.atomic import atomic_savefig  # noqa: E402
from tvrecon.utils.output_dir import announce, output_dir  # noqa: E402
from tvrecon.utils.shape_check import check_shape  # noqa: E402

__all__ = ["make_preview", "draw_preview", "save_figure_atomic", "main"]


def save_figure_atomic(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    """Write `fig` as a PNG at `path` atomically (temp file in the same folder, then os.replace)."""
    return atomic_savefig(fig, path, format="png", dpi=dpi, bbox_inches="tight", facecolor="white")


def _grid(n: int) -> tuple[int, int]:
    rows = 1 if n <= 3 else 2 if n <= 8 else 3
    return rows, math.ceil(n / rows)


def draw_preview(
    image: torch.Tensor,
    camera: Camera,
    positions: torch.Tensor,
    directions: torch.Tensor,
    tactile: torch.Tensor,
    labels: list[str] | None = None,
    title: str = "",
    arrow_length: float = 0.18,
) -> Figure:
    """Draw the view with the projected touches next to their tactile images.

    Args:
        image: (3, H, W) float view in [0, 1].
        camera: the view's camera (for projecting the touches).
        positions: (T, 3) world contact points. directions: (T, 3) world unit press directions.
        tactile: (T, 3, h, w) tactile images (x shear, y shear, z normal displacement, grid cells).
        labels: T captions under the tactile images (default: none).
        title: figure title.
        arrow_length: world length of the direction arrows.

    Returns:
        the matplotlib Figure (caller saves and closes it).
    """
    check_shape(image, "(3, H, W)", "image")
    check_shape(positions, "(T, 3)", "positions")
    check_shape(directions, "(T, 3)", "directions")
    check_shape(tactile, "(T, 3, h, w)", "tactile")
    T = positions.shape[0]
    if directions.shape[0] != T or T < 1:
        raise ValueError(
            f"positions and directions must have shape (T, 3) with T >= 1, got {tuple(positions.shape)} and "
            f"{tuple(directions.shape)}"
        )
    if tactile.shape[0] != T:
        raise ValueError(f"tactile must have shape (T, 3, h, w) with T={T}, got {tuple(tactile.shape)}")
    colours = plt.get_cmap("tab10")(np.arange(T) % 10)
    rows, cols = _grid(T)
    fig = plt.figure(figsize=(5.2 + 2.3 * cols, 5.6), layout="constrained")
    sub_view, sub_tac = fig.subfigures(1, 2, width_ratios=[5.2, 2.3 * cols])

    # --- the view with the projected touches
    ax = sub_view.subplots()
    H, W = image.shape[1:]
    ax.imshow(image.permute(1, 2, 0).clamp(0, 1).cpu().numpy(), extent=(-0.5, W - 0.5, H - 0.5, -0.5))
    pos = positions.float().cpu()
    d = directions.float().cpu()
    uv = project_points(pos, camera.K, camera.RT).numpy()  # (T, 2) contact points
    uv_tail = project_points(pos - arrow_length * d, camera.K, camera.RT).numpy()  # where the pad comes from
    for t in range(T):
        ax.annotate(
            "",
            xy=uv[t],
            xytext=uv_tail[t],
            arrowprops={
                "arrowstyle": "-|>",
                "color": colours[t],
                "lw": 2.2,
                "mutation_scale": 14,
                "shrinkA": 0,
                "shrinkB": 3,
            },
        )
        ax.scatter(*uv[t], s=46, color=colours[t], edgecolor="white", linewidth=1.2, zorder=3)
        ax.annotate(
            str(t + 1),
            uv_tail[t],
            textcoords="offset points",
            xytext=(0, 0),
            ha="center",
            va="center",
            fontsize=9,
            fontweight="bold",
            color="white",
            bbox={"boxstyle": "circle,pad=0.2", "fc": colours[t], "ec": "white", "lw": 0.8},
        )
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.set_axis_off()
    ax.set_title("view + touches (arrow = press direction)", fontsize=10)

    # --- the tactile images: normal displacement as colour, shear as arrows, on one shared scale
    tac = tactile.detach().float().cpu()
    normal = tac[:, 2].numpy()
    vmax = max(float(np.abs(normal).max()), 1e-6)
    axes = np.atleast_1d(sub_tac.subplots(rows, cols)).ravel()
    im = None
    for t, a in enumerate(axes):
        a.set_xticks([])
        a.set_yticks([])
        if t >= T:
            a.set_axis_off()
            continue
        h, w = normal.shape[1:]
        im = a.imshow(normal[t], cmap="magma", vmin=-0.1 * vmax, vmax=vmax, interpolation="bilinear")
        step = max(1, min(h, w) // 10)
        ys, xs = np.mgrid[step // 2 : h : step, step // 2 : w : step]
        sx, sy = tac[t, 0].numpy()[ys, xs], tac[t, 1].numpy()[ys, xs]
        mag = np.hypot(sx, sy)
        keep = mag > 0.05 * max(float(mag.max()), 1e-6)  # hide the sea of zero-length arrows off contact
        if keep.any() and mag.max() > 1e-3 * vmax:
            a.quiver(xs[keep], ys[keep], sx[keep], sy[keep], color="white", alpha=0.85, angles="xy", width=0.012)
        for s in a.spines.values():
            s.set_edgecolor(colours[t])
            s.set_linewidth(3)
        a.set_title(f"{t + 1}" + (f"  {labels[t]}" if labels else ""), fontsize=9, color=colours[t])
    if im is not None:
        cb = sub_tac.colorbar(im, ax=axes.tolist(), shrink=0.85, pad=0.02)
        cb.set_label("normal displacement (grid cells)", fontsize=9)
    sub_tac.suptitle("tactile images (arrows: shear)", fontsize=10)
    if title:
        fig.suptitle(title, fontsize=12, fontweight="bold")
    return fig


def make_preview(
    out: str | Path,
    shape: str = "mug",
    touches: int = 6,
    seed: int = 0,
    image_size: int = 224,
    pad: int = 64,
    n_grid: int = 128,
    cone_deg: float = 15.0,
    fov_deg: float = 45.0,
    device: str = "cpu",
) -> Path:
    """Generate one sample (object, view, touches, tactile readings) and write its preview PNG to `out`.

    Args:
        out: PNG path (written atomically).
        shape: object class of the procedural library, or a mesh file.
        touches: number of touches T.
        seed: seeds the object instance, camera, colours, and touches.
        image_size: view side in pixels.
        pad: sensor contact-layer resolution (pad x pad particles); smaller is faster.
        n_grid: simulation grid cells across the press domain.
        cone_deg: half-angle of the press-direction cone around the inward normal.
        fov_deg: camera field of view in degrees (camera at distance 2 from the object centre).
        device: torch device of the simulation.

    Returns:
        the written path.
    """
    from tvrecon.data.shapes.shape_arg import shape_or_mesh_file
    from tvrecon.sim.press.config import PressConfig
    from tvrecon.sim.press.simulator import EIPSimulator
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    if int(touches) < 1:
        raise ValueError(f"touches must be >= 1, got {touches}")
    mesh, note = shape_or_mesh_file(shape, seed=seed, what="shape")  # any object class or a mesh file
    if note:
        print(note, flush=True)
    shape = Path(shape).name if Path(shape).suffix else shape  # the title names a file by its name
    camera = sample_camera(seed, image_size=image_size, fov_deg=fov_deg)
    view = render_view(mesh, camera, seed=seed)
    policy = ConeTouchPolicy(cone_deg=cone_deg, visible_only=True)
    sim = EIPSimulator(SensorConfig(resolution=(pad, pad)), PressConfig(n_grid=n_grid), device=device)
    tt = sample_touches(mesh, touches, seed, policy, camera=camera, sim=sim)  # only touches the pad can reach
    readings = simulate_touches(sim, mesh, tt, progress=True)
    tactile = torch.stack([r.image.detach().cpu() for r in readings])  # (T, 3, h, w)
    labels = []
    for r, s in zip(readings, tt.strengths):
        rule = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}" for k, v in s.items())
        labels.append(f"depth {r.depth:.1f} ({rule})" if r.contact else "no contact")
    fig = draw_preview(
        view["image"],
        camera,
        tt.positions,
        tt.directions,
        tactile,
        labels=labels,
        title=f"{shape}  ·  seed {seed}  ·  {touches} touches  ·  pad {pad}x{pad}",
    )
    try:
        return save_figure_atomic(fig, out)
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m tvrecon.data.preview", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=None, help="PNG file to write (default outputs/preview/<time>/preview.png)")
    p.add_argument("--shape", default="mug", help="an object class of the library (default: mug) or a mesh file")
    p.add_argument("--touches", type=int, default=6, help="number of touches (default: 6)")
    p.add_argument("--seed", type=int, default=0, help="seed of object instance, view and touches (default: 0)")
    p.add_argument("--image-size", type=int, default=224, help="view side in pixels (default: 224)")
    p.add_argument("--pad", type=int, default=64, help="sensor resolution, pad x pad particles (default: 64)")
    p.add_argument("--n-grid", type=int, default=128, help="simulation grid cells across the domain (default: 128)")
    p.add_argument("--cone", type=float, default=15.0, help="press-direction cone half-angle, degrees")
    p.add_argument("--fov", type=float, default=45.0, help="camera field of view, degrees (default: 45)")
    p.add_argument("--device", default="cpu", help="torch device of the simulation")
    a = p.parse_args(argv)
    out = a.out if a.out else output_dir(None, "preview") / "preview.png"
    path = make_preview(out, a.shape, a.touches, a.seed, a.image_size, a.pad, a.n_grid, a.cone, a.fov, a.device)
    print(f"wrote {path.name}")
    announce(path.parent)
    return 0


if __name__ == "__main__":
    from tvrecon.utils.cli_errors import run_cli

    run_cli(main, prog="python -m tvrecon.data.preview")  # errors: one line, exit 2/1/130
