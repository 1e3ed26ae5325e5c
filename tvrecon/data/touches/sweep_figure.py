"""Pictures of a preset's touches: one object's sweep of touches, and a contact sheet of one touch per class.

    python -m tvrecon.data.touches.sweep_figure sweep [--out sweep.png --preset cls_paper_cpu --shape gear --seed 0]
    python -m tvrecon.data.touches.sweep_figure sheet [--out sheet.png --preset cls_paper_cpu --elevation 45]

Without ``--out`` the picture goes to ``outputs/sweep_figure/<time>/<kind>.png``; the folder is printed at the end.

The touches come from the preset's own touch policy, pad and grid (``configs/data/<preset>.yaml``), pressed with the
EIP simulator on the library's training objects; each tile shows the normal displacement of the contact layer (cells
pushed into the pad), the way the paper's dataset figure shows an object pressed along a sweep of directions.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: this module only writes files

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from hydra.utils import instantiate  # noqa: E402

from tvrecon.data.dataset_base import GeneratedDataset  # noqa: E402
from tvrecon.data.presets import compose_preset  # noqa: E402
from tvrecon.data.touches.policies import sample_touches, simulate_touches  # noqa: E402
from tvrecon.data.views import render_view, sample_camera  # noqa: E402
from tvrecon.utils.atomic import atomic_savefig  # noqa: E402
from tvrecon.utils.output_dir import announce, output_dir  # noqa: E402

__all__ = ["preset_dataset", "sweep_figure", "contact_sheet", "main"]

PROG = "python -m tvrecon.data.touches.sweep_figure"


def preset_dataset(preset: str, overrides: Sequence[str] = ()) -> GeneratedDataset:
    """The training dataset of a data preset (its library, pad, grid and touch policy), caching disabled."""
    dm = instantiate(compose_preset(preset, [*overrides, "cache_dir=null"]), _convert_="all")
    return dm.make_dataset("train")


def _press(ds: GeneratedDataset, cls: str, n: int, seed: int, policy=None) -> tuple[np.ndarray, object, object]:
    """(n, Hs, Ws) normal images, (n,) contact flags and the touches of ``n`` touches on train instance ``seed`` of
    ``cls``."""
    mesh = ds.library.get(cls, seed, "train")
    touches = sample_touches(mesh, n, seed=seed, policy=policy or ds.touch, sim=ds.simulator)
    readings = simulate_touches(ds.simulator, mesh, touches, batch_size=n)
    images = torch.stack([r.image[2] for r in readings]).float().cpu().numpy()
    return images, np.array([bool(r.contact) for r in readings]), touches


def sweep_figure(ds: GeneratedDataset, shape: str, seed: int = 0, touches: int = 10) -> plt.Figure:
    """One object's touches: a rendered view, then each touch's normal image titled with its elevation."""
    images, _, t = _press(ds, shape, touches, seed)
    mesh = ds.library.get(shape, seed, "train")
    vmax = max(float(images.max()), 1e-6)
    fig, axes = plt.subplots(1, touches + 1, figsize=(1.6 * (touches + 1), 2.0))
    view = render_view(mesh, sample_camera(seed, image_size=160, distance=2.2), seed=seed)["image"]
    axes[0].imshow(view.permute(1, 2, 0).numpy())
    axes[0].set_title(f"{shape}", fontsize=9)
    elev = np.degrees(np.arcsin(np.clip(-t.directions[:, 2].double().numpy(), -1, 1)))
    for k, ax in enumerate(axes[1:]):
        ax.imshow(images[k], cmap="viridis", vmin=0.0, vmax=vmax, origin="lower")
        ax.set_title(f"{elev[k]:.0f} deg", fontsize=8)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(
        f"{shape}: {touches} touches from the side (0 deg) to the top (90 deg) through the centre; normal "
        f"displacement, 0-{vmax:.2f} cells",
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def contact_sheet(ds: GeneratedDataset, elevation: float = 45.0, seed: int = 0, columns: int = 7) -> plt.Figure:
    """One touch per class at one elevation of the sweep, each tile scaled to its own maximum."""
    policy = ds.touch
    if dataclasses.is_dataclass(policy) and hasattr(policy, "elevation_deg"):
        policy = dataclasses.replace(policy, elevation_deg=(float(elevation), float(elevation)))
    rows = -(-len(ds.classes) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(1.5 * columns, 1.6 * rows))
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
        ax.axis("off")
    for ax, cls in zip(axes.flat, ds.classes, strict=False):
        images, contact, _ = _press(ds, cls, 1, seed, policy)
        ax.imshow(images[0], cmap="viridis", vmin=0.0, vmax=max(float(images[0].max()), 1e-6), origin="lower")
        ax.set_title(cls if contact[0] else f"{cls} (no contact)", fontsize=8)
    fig.suptitle(
        f"one touch per class at {elevation:.0f} deg: normal displacement, each tile to its own max", fontsize=9
    )
    fig.tight_layout()
    return fig


def main(argv: Sequence[str] | None = None) -> Path:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    p.add_argument("kind", choices=("sweep", "sheet"), help="one object's sweep, or one touch per class")
    p.add_argument("--out", default=None, type=Path, help="PNG file to write (default outputs/sweep_figure/<time>/)")
    p.add_argument("--preset", default="cls_paper_cpu", help="data preset (configs/data), default cls_paper_cpu")
    p.add_argument("--shape", default="gear", help="object class of the sweep (default: gear)")
    p.add_argument("--seed", type=int, default=0, help="training instance and touch seed (default: 0)")
    p.add_argument("--touches", type=int, default=10, help="touches of the sweep (default: 10)")
    p.add_argument("--elevation", type=float, default=45.0, help="elevation of the sheet's touches, degrees")
    p.add_argument("overrides", nargs="*", help="Hydra overrides of the preset, e.g. press.n_grid=40")
    args = p.parse_intermixed_args(argv)  # overrides after the options too: `sweep --shape gear press.n_grid=40`
    if args.touches < 1:
        p.error(f"--touches must be >= 1, got {args.touches}")
    if not -90.0 <= args.elevation <= 90.0:  # checked before the preset's dataset is built
        raise ValueError(f"--elevation must be in [-90, 90] degrees (0: the side, 90: the top), got {args.elevation:g}")
    torch.set_num_threads(1)
    ds = preset_dataset(args.preset, args.overrides)
    if args.kind == "sweep" and args.shape not in ds.classes:
        classes = ", ".join(ds.classes)
        raise ValueError(f"--shape {args.shape!r} is not a class of preset {args.preset!r}; its classes: {classes}")
    if args.kind == "sweep":
        fig = sweep_figure(ds, args.shape, args.seed, args.touches)
    else:
        fig = contact_sheet(ds, args.elevation, args.seed)
    target = args.out if args.out is not None else output_dir(None, "sweep_figure") / f"{args.kind}.png"
    out = Path(atomic_savefig(fig, target, format="png", dpi=110, bbox_inches="tight", facecolor="white"))
    plt.close(fig)
    print(f"wrote {out.name}")
    announce(out.parent)
    return out


if __name__ == "__main__":
    from tvrecon.utils.cli_errors import run_cli

    run_cli(main, prog=PROG)  # errors: one line, exit 2 (bad input) / 1 / 130
