"""Press a real sensor's pad onto your own mesh file and save what it feels.

    python examples/press_my_mesh.py part.stl --units mm --sensor digit --out outputs/my_press
    python examples/press_my_mesh.py part.stl --units mm --position 12 0 30 --direction -1 0 0 --depth-mm 0.5

The mesh keeps its own size: ``--units`` says what one unit of the file is, and the pad is the ``--sensor``
preset's real size (``tvrecon.sim.sensor.presets``: the domain spans ``domain_mm`` millimetres, see
``docs/guides/sensor-outputs.md``). ``--position`` is a point of the file in the file's units (default: the first
surface the pad meets along ``--direction``). Writes into ``--out``:

- ``tactile.png``: the contact layer's displacement (normal colormap, shear arrows), in grid cells;
- ``force.png`` and ``force_field.npy``: the force per taxel, (H, W, 3) in the sensor frame, in newtons;
- ``contact_patch.ply`` and ``contact_patch.npz``: the contact layer's points in the file's units, with a mask of
  those in contact;
- ``summary.json``: total force (N), depth (mm), taxels in contact, steps.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, reading_patch
from tvrecon.sim.plots import save_force_png, save_ply, save_tactile_png
from tvrecon.sim.sensor.presets import SENSOR_PRESETS
from tvrecon.utils.atomic import atomic_open, atomic_write_text
from tvrecon.utils.cli_errors import run_cli

#: millimetres per unit of the mesh file
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="press_my_mesh.py", description=__doc__.split("\n\n")[0])
    p.add_argument("mesh", type=Path, help="mesh file (.stl, .obj, .ply, .glb, ...)")
    p.add_argument("--units", choices=sorted(UNITS_MM), default="mm", help="what one unit of the file is")
    p.add_argument("--sensor", choices=sorted(SENSOR_PRESETS), default="digit", help="real sensor preset")
    p.add_argument("--position", type=float, nargs=3, default=None, help="touch point in the file's units")
    p.add_argument("--direction", type=float, nargs=3, default=(0.0, 0.0, -1.0), help="press direction, into it")
    p.add_argument("--depth-mm", type=float, default=None, help="stop at this indentation (default: eq. 12)")
    p.add_argument("--n-grid", type=int, default=128, help="grid cells across the domain (64: faster, coarser)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default outputs/press_my_mesh/<time>)")
    return p


def load_mesh_mm(path: Path, units: str) -> trimesh.Trimesh:
    """The mesh file as one trimesh in millimetres; a missing or empty file is a ValueError naming it."""
    if not path.is_file():
        raise ValueError(f"mesh file {path} does not exist; give the path of a .stl/.obj/.ply/.glb file")
    mesh = trimesh.load(path, force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path} holds no triangles; export the part as a triangle mesh")
    mesh.apply_scale(UNITS_MM[units])
    return mesh


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    mesh = load_mesh_mm(args.mesh, args.units)
    preset = SENSOR_PRESETS[args.sensor]
    cell_mm = preset.cell_mm(args.n_grid)
    press = PressConfig(n_grid=args.n_grid, **preset.press_overrides(args.n_grid))
    if args.depth_mm is not None:
        press = dataclasses.replace(press, depth=args.depth_mm / cell_mm)
    sim = EIPSimulator(preset.sensor_config(args.n_grid), press)
    scale = UNITS_MM[args.units]
    position = None if args.position is None else [c * scale for c in args.position]
    reading = sim.press(mesh, position, list(args.direction))

    out = args.out or Path("outputs/press_my_mesh") / time.strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    newton = preset.force_unit_newton(args.n_grid)
    save_tactile_png(reading.image, out / "tactile.png", title=f"{preset.title} on {args.mesh.name}")
    field = reading.force_field * newton  # (H, W, 3) newtons, sensor frame
    save_force_png(field, out / "force.png", title=f"force per taxel (N), total {float(field[..., 2].sum()):.3g}")
    with atomic_open(out / "force_field.npy") as f:
        np.save(f, field.numpy())
    patch = reading_patch(reading, sim.sensor, sim.cfg)
    points = patch.points / scale  # (H*W, 3) in the file's units
    save_ply(points[patch.mask], out / "contact_patch.ply")
    with atomic_open(out / "contact_patch.npz") as f:
        np.savez(f, points=points.numpy(), normals=patch.normals.numpy(), mask=patch.mask.numpy())
    summary = {
        "sensor": args.sensor,
        "contact": bool(reading.contact),
        "force_N": [round(float(x) * newton, 6) for x in reading.force],
        "depth_mm": round(float(reading.depth) * cell_mm, 6),
        "taxels_in_contact": int(patch.mask.sum()),
        "steps": int(reading.steps),
        "cell_mm": cell_mm,
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    print(f"{args.mesh.name}: {summary['taxels_in_contact']} taxels in contact, depth {summary['depth_mm']:.3f} mm, "
          f"normal force {float(torch.as_tensor(reading.force).norm()) * newton:.3g} N -> {out}")
    return 0


if __name__ == "__main__":
    run_cli(main, prog="press_my_mesh.py")
