"""Command line: one EIP press with pictures.

    python -m tvrecon.sim press --shape torus --direction 0 0 -1 --out outputs/sim_demo
    python -m tvrecon.sim press --shape mug          # any object class of the library, or a mesh file

Without ``--out`` the files go to ``outputs/sim_press/<time>/``; the folder is printed at the end. A press into a
folder that holds an earlier press replaces that press's files.

Writes ``tactile.png`` (normal displacement + shear arrows), ``reading.npz`` (every field of the reading),
``pad_step*.ply`` (pad particles, world coordinates, a few steps), ``deformation.png`` (the press over time) and,
with ``--surface``, ``pad_surface.ply`` (marching-cubes mesh of the deformed pad). ``--outputs force markers rgb``
adds ``force.png`` (per-taxel normal/shear force), ``markers.png`` (marker grid as a camera behind the pad sees it),
``rgb.png`` (GelSight-style photometric image) and ``outputs.png`` (all of them beside the displacement).
``--sensor digit`` (or ``gelsight_mini``, ``gelsight_r15``, ``tactip``) presses a pad with that sensor's size,
thickness and material (``tvrecon.sim.sensor.presets``, ``docs/guides/sensor-outputs.md``).
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np
import torch
import trimesh

from tvrecon.sim.mpm.state import CONTACT_MODES
from tvrecon.sim.plots import save_ply, save_sequence_png, save_tactile_png
from tvrecon.sim.press.config import TERMINAL_MEASURES, PressConfig
from tvrecon.sim.press.reading import TactileReading
from tvrecon.sim.press.simulator import EIPSimulator
from tvrecon.sim.sensor.elastic_pad import SensorConfig
from tvrecon.sim.sensor.presets import SENSOR_PRESETS
from tvrecon.utils.atomic import atomic_write_bytes
from tvrecon.utils.cli_errors import call_cli
from tvrecon.utils.output_dir import OUTPUTS, announce, check_writable_dir, output_dir

SENSOR_PRESET_NAMES = tuple(SENSOR_PRESETS)
PROG = "python -m tvrecon.sim"
#: the folder name of this CLI's runs under outputs/ when --out is not given
TOOL = "sim_press"
#: the files of a press in its --out folder (pad_step*.ply besides): an earlier press's are replaced, not mixed in
PRESS_FILES = ("tactile.png", "reading.npz", "deformation.png", "pad_surface.ply", "force.png", "markers.png",
               "rgb.png", "outputs.png")  # fmt: skip
#: --compile values -> EIPSimulator(compile=...)
COMPILE_CHOICES = {"auto": "auto", "true": True, "false": False}

SENSOR_OUTPUTS = ("force", "markers", "rgb")
#: The press defaults the ``--contact`` and ``--threshold-grid`` flags follow.
PRESS_DEFAULTS = PressConfig()


def threshold_grid_arg(text: str) -> int | None:
    """``--threshold-grid N``: a positive N (``PressConfig.threshold_grid``), or 0 for None (the press's own cells)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 (0: the press's own cells), got {value}")
    return value or None


def load_shape(name: str, seed: int = 0) -> trimesh.Trimesh:
    """An object class of the library (any of the 35; ``sphere`` = ``ball``) or a mesh file (.obj, .ply, .stl, ...).

    Mesh files are centred at their bounding-box centre and scaled to a largest extent of 1, like the library
    (:func:`tvrecon.data.shapes.shape_arg.shape_or_mesh_file`, the one meaning of ``--shape``).
    """
    from tvrecon.data.shapes.shape_arg import shape_or_mesh_file  # entry point: may use any layer

    mesh, note = shape_or_mesh_file(name, seed=seed, what="--shape", positions="--position")
    if note:  # --position is in the rescaled units: say so
        print(note, flush=True)
    return mesh


def save_reading_npz(reading: TactileReading, path: str | Path) -> Path:
    """Every field of a reading in one .npz (atomic)."""
    arrays = {}
    for key, val in vars(reading).items():
        if val is None:
            continue
        arrays[key] = val.detach().cpu().numpy() if isinstance(val, torch.Tensor) else np.asarray(val)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def to_sensor_cells(points: torch.Tensor, reading: TactileReading, press: PressConfig) -> np.ndarray:
    """(P, 3) world -> (P, 3) sensor frame in grid cells, relative to the touch point."""
    assert reading.frame is not None and reading.origin is not None
    local = (points - reading.origin) @ reading.frame / float(press.domain_size) * int(press.n_grid)
    return local.numpy()


def check_outputs(args: argparse.Namespace) -> Path:
    """Check the output options before the simulation runs (it takes minutes); create ``--out``. Returns it.

    Raises:
        ValueError: ``--out`` is a file, under a file, or not writable; ``--frames`` < 1 (deformation.png and the
            .ply files need a frame) or ``--ply`` < 0.
    """
    if args.threads < 0:
        raise ValueError(f"--threads must be >= 0 (0: torch's default number of threads), got {args.threads}")
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1 (frames drawn in deformation.png), got {args.frames}")
    if args.ply < 0:
        raise ValueError(f"--ply must be >= 0 (pad .ply files of the last frames; 0 writes none), got {args.ply}")
    if not (args.marker_spacing > 0 and args.marker_radius > 0 and args.height_gain > 0):
        raise ValueError(
            f"--marker-spacing, --marker-radius and --height-gain must be > 0, got {args.marker_spacing}, "
            f"{args.marker_radius} and {args.height_gain}"
        )
    return check_writable_dir(output_dir(args.out, TOOL), "--out ")


def run_press(args: argparse.Namespace) -> dict[str, Path]:
    """Run one press from parsed CLI arguments and write its files; returns {name: path}."""
    out = check_outputs(args)
    earlier = (out / "reading.npz").is_file()  # a second press into one folder: the first's files are replaced
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    mesh = load_shape(args.shape, seed=args.seed)
    direction = np.asarray(args.direction, dtype=np.float64)
    if not np.isfinite(direction).all() or np.linalg.norm(direction) < 1e-8:
        raise ValueError(f"--direction must be a non-zero vector, got {args.direction}")
    position = np.asarray(args.position, dtype=np.float64) if args.position else None
    sensor, press_extra = cli_sensor(args)
    press = PressConfig(
        n_grid=args.n_grid,
        depth=args.depth,
        force=args.force,
        contact=args.contact,
        threshold_grid=args.threshold_grid,
        terminal=args.terminal,
        record_every=1,
        progress=True,
        release_steps=0,
        **press_extra,
    )
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {args.device}: torch sees no CUDA device here (torch {torch.__version__}); use cpu")
    sim = EIPSimulator(sensor, press, device=device, compile=COMPILE_CHOICES[args.compile])
    # without --position: the first surface the pad meets along --direction, its footprint clear of the object
    reading = sim.press(mesh, position, direction).cpu()  # pictures and files from host copies
    if position is None:
        assert reading.origin is not None
        print(f"touch position (no --position given): {np.round(reading.origin.numpy(), 4).tolist()}")
    files: dict[str, Path] = {}
    files["tactile"] = save_tactile_png(
        reading.image,
        out / "tactile.png",
        title=f"{Path(args.shape).stem}: {reading.steps} steps, depth {reading.depth:.2f} cells, "
        f"chamfer {reading.chamfer:.3g}",
    )
    files["npz"] = save_reading_npz(reading, out / "reading.npz")
    if reading.frames is not None and reading.particles is not None:
        K = len(reading.frames)
        pick = sorted({int(round(i)) for i in np.linspace(0, K - 1, min(args.frames, K))})
        H, W = sensor.resolution
        L = sensor.layers
        # the middle particle row through the thickness, in the sensor frame
        sections = [to_sensor_cells(reading.particles[k], reading, press).reshape(L, H, W, 3)[:, H // 2] for k in pick]
        sections = [sec.reshape(-1, 3) for sec in sections]
        files["sequence"] = save_sequence_png(
            reading.frames[pick],
            out / "deformation.png",
            steps=[reading.frame_steps[k] for k in pick],
            sections=sections,
        )
        # pick[-0:] would be every frame: --ply 0 must write none
        for k in pick[len(pick) - min(max(args.ply, 0), len(pick)) :]:
            normal = reading.frames[k][2].reshape(-1)
            values = torch.cat([normal, torch.zeros(reading.particles.shape[1] - H * W)])
            files[f"ply{k}"] = save_ply(reading.particles[k], out / f"pad_step{reading.frame_steps[k]:04d}.ply", values)
        if args.surface:
            from tvrecon.sim.sensor.surface import pad_surface

            spacing_world = sensor.spacing * press.domain_size / press.n_grid
            surf = pad_surface(reading.particles[pick[-1]], spacing=spacing_world)
            files["surface"] = atomic_write_bytes(out / "pad_surface.ply", surf.export(file_type="ply"))
    if args.outputs:
        files.update(write_sensor_outputs(reading, sensor, args, out))
    print(
        f"contact={reading.contact} steps={reading.steps} depth={reading.depth:.3f} cells "
        f"max normal={float(reading.image[2].max()):.3f} cells chamfer={reading.chamfer:.4g} "
        f"force={[round(v, 4) for v in reading.force.tolist()]}"
    )
    if earlier:
        replaced = remove_earlier_press(out, set(files.values()))
        print(f"--out {out} held an earlier press: its files are replaced ({replaced} of them removed)", flush=True)
    for path in files.values():
        print(f"wrote {path.name}")
    announce(out)
    if reading.criterion_missed:
        asked = "--depth" if args.depth is not None else "--force" if args.force is not None else "the threshold"
        msg = (
            f"the press stopped at its travel limit before {asked} was reached (depth {reading.depth:.2f} cells, "
            f"normal force {float(reading.force_field[..., 2].sum()) if reading.force_field is not None else 0:.4g})"
        )
        if args.strict:
            raise StopNotReached(f"{msg}; the files above are written (--strict makes this an error)")
        print(f"warning: {msg}; add --strict to make this an error", file=sys.stderr, flush=True)
    return files


def remove_earlier_press(out: Path, keep: set[Path]) -> int:
    """Remove the files of an earlier press in ``out`` that this press did not write (its ``pad_step*.ply`` of other
    steps, an image this press does not draw); returns how many."""
    keep = {Path(p).resolve() for p in keep}
    stale = [*out.glob("pad_step*.ply"), *(out / name for name in PRESS_FILES)]
    removed = 0
    for path in stale:
        if path.is_file() and path.resolve() not in keep:
            path.unlink()
            removed += 1
    return removed


class StopNotReached(RuntimeError):
    """``--strict``: the press ended at its travel limit, not at the asked ``--depth`` / ``--force`` / threshold."""


def cli_sensor(args: argparse.Namespace) -> tuple[SensorConfig, dict]:
    """The pad of a CLI run and the PressConfig fields that go with it.

    Without ``--sensor``: the flags (defaults: a 64x64 pad, 6 layers, E 3, nu 0.25). With ``--sensor NAME``: the
    preset's pad at ``--n-grid`` (``tvrecon.sim.sensor.presets``) and its hand speed; ``--resolution``, ``--layers``,
    ``--E`` and ``--nu`` given explicitly still override it. Meshes stay in the CLI's unit-extent scale, so the
    printed scale says how many mm one cell and the object stand for.
    """
    fields = {"alpha_profile": args.profile, "damping": args.damping}
    press_extra: dict = {}
    if args.sensor:
        preset = SENSOR_PRESETS[args.sensor]
        base = preset.sensor_config(args.n_grid)
        fields.update(resolution=base.resolution, layers=base.layers, E=base.E, nu=base.nu)
        press_extra["speed_fraction"] = preset.press_overrides(args.n_grid)["speed_fraction"]
        H, W = base.resolution
        cell, obj = preset.cell_mm(args.n_grid), preset.domain_mm(args.n_grid)
        print(
            f"sensor {preset.title}: {W}x{H} pad, {base.layers} layers, E {base.E} (x100 kPa), nu {base.nu}; "
            f"1 cell = {cell:.3f} mm, the unit-extent object = {obj:.1f} mm"
        )
    else:
        fields.update(resolution=(64, 64), layers=6, E=3.0, nu=0.25)
    if args.resolution is not None:
        fields["resolution"] = (args.resolution, args.resolution)
    for name in ("layers", "E", "nu"):
        if getattr(args, name) is not None:
            fields[name] = getattr(args, name)
    return SensorConfig(**fields), press_extra


def write_sensor_outputs(
    reading: TactileReading, sensor: SensorConfig, args: argparse.Namespace, out: Path
) -> dict[str, Path]:
    """``force.png``, ``markers.png``, ``rgb.png`` (those in ``args.outputs``) and ``outputs.png``; {name: path}."""
    from tvrecon.sim.plots import (
        auto_arrow_gain,
        save_force_png,
        save_markers_png,
        save_outputs_png,
        save_rgb_png,
    )
    from tvrecon.sim.sensor.markers import marker_displacements, marker_grid, render_markers
    from tvrecon.sim.sensor.photometric import render_rgb

    files: dict[str, Path] = {}
    image = reading.image.detach().cpu()
    field = markers = rgb = None
    gain = 1.0
    if "force" in args.outputs and reading.force_field is not None:
        field = reading.force_field
        files["force"] = save_force_png(field, out / "force.png")
    if "markers" in args.outputs:
        rest = marker_grid(sensor.resolution, spacing=args.marker_spacing)
        disp = marker_displacements(image, rest, taxel_spacing=sensor.spacing)
        ppt = 4
        dots = render_markers(rest + disp, sensor.resolution, radius=args.marker_radius, pixels_per_taxel=ppt)
        markers = (dots, rest, disp, ppt)
        gain = auto_arrow_gain(disp.numpy(), args.marker_spacing)
        files["markers"] = save_markers_png(dots, rest, disp, out / "markers.png", ppt, arrow_gain=gain)
    if "rgb" in args.outputs:
        rgb = render_rgb(image, taxel_spacing=sensor.spacing, height_gain=args.height_gain)
        files["rgb"] = save_rgb_png(rgb, out / "rgb.png")
    files["outputs"] = save_outputs_png(
        out / "outputs.png", image, field=field, markers=markers, arrow_gain=gain, rgb=rgb
    )
    return files


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("press", help="press the sensor pad onto a shape and write pictures")
    p.add_argument("--shape", default="torus", help="an object class of the library (default torus) or a mesh file")
    p.add_argument("--seed", type=int, default=0, help="instance seed of a library shape")
    p.add_argument("--direction", type=float, nargs=3, default=[0.0, 0.0, -1.0], help="press direction (into object)")
    p.add_argument(
        "--position", type=float, nargs=3, default=None, help="touch point (default: the first surface the pad meets)"
    )
    p.add_argument("--out", default=None, help=f"output folder (default {OUTPUTS}/{TOOL}/<time>)")
    p.add_argument(
        "--sensor",
        choices=SENSOR_PRESET_NAMES,
        default=None,
        help="pad preset of a real sensor (docs/guides/sensor-outputs.md): its size, thickness, E, nu at --n-grid",
    )
    p.add_argument("--E", type=float, default=None, help="Young's modulus (default 3, or the --sensor preset's)")
    p.add_argument("--nu", type=float, default=None, help="Poisson ratio (default 0.25, or the --sensor preset's)")
    p.add_argument("--depth", type=float, default=None, help="stop at this indentation (cells)")
    p.add_argument("--force", type=float, default=None, help="stop at this normal force")
    p.add_argument("--profile", choices=("clamped", "linear"), default="clamped", help="alpha profile")
    p.add_argument(
        "--contact",
        choices=CONTACT_MODES,
        default=PRESS_DEFAULTS.contact,
        help=f"collider on grid nodes or on the pad's particles (default {PRESS_DEFAULTS.contact})",
    )
    p.add_argument(
        "--threshold-grid",
        type=threshold_grid_arg,
        default=PRESS_DEFAULTS.threshold_grid,
        metavar="N",
        help=f"terminal threshold in squared cells of an N-cell grid (default {PRESS_DEFAULTS.threshold_grid}); "
        "0: in the press's own cells (--contact grid --threshold-grid 0 is the earlier default press)",
    )
    p.add_argument(
        "--terminal",
        choices=TERMINAL_MEASURES,
        default=PRESS_DEFAULTS.terminal,
        help=f"what the terminal threshold measures (default {PRESS_DEFAULTS.terminal}: paper eq. 12); displacement: "
        "the same deformation matched particle to particle, one deformation at every --n-grid on flat faces",
    )
    p.add_argument("--damping", type=float, default=0.0, help="grid velocity damping rate")
    p.add_argument("--resolution", type=int, default=None, help="tactile image size H = W (default 64, or --sensor's)")
    p.add_argument("--layers", type=int, default=None, help="pad thickness in particles (default 6, or --sensor's)")
    p.add_argument("--n-grid", type=int, default=128, help="grid cells across the domain")
    p.add_argument("--frames", type=int, default=5, help="frames in deformation.png")
    p.add_argument("--ply", type=int, default=3, help="pad .ply files to write (last frames)")
    p.add_argument("--surface", action="store_true", help="also write a marching-cubes mesh of the pad")
    p.add_argument(
        "--outputs", nargs="+", choices=SENSOR_OUTPUTS, default=[], help="sensor outputs to draw beyond displacement"
    )
    p.add_argument("--marker-spacing", type=float, default=4.0, help="marker grid spacing (taxels)")
    p.add_argument("--marker-radius", type=float, default=1.0, help="marker dot radius (taxels)")
    p.add_argument("--height-gain", type=float, default=3.0, help="height exaggeration of the RGB image")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch default)")
    p.add_argument("--device", default="cpu", help="torch device of the simulation (cpu, cuda, cuda:1, ...)")
    p.add_argument(
        "--compile",
        choices=tuple(COMPILE_CHOICES),
        default="auto",
        help="the solver's fused torch.compile kernels (auto: a single press stays eager; a compile costs ~20-120 s)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 when the press ends at its travel limit before --depth / --force / the threshold is reached",
    )
    p.add_argument("--debug", action="store_true", help="on an error, show the full traceback (not one line)")
    return parser


def _main(argv: list[str]) -> int:
    run_press(build_parser().parse_args(argv))
    return 0


def main(argv: list[str] | None = None) -> int:
    """The press CLI; returns the exit status: 0, 2 (bad input, one line on stderr), 1 (the press failed).

    ``--debug`` keeps the traceback (``tvrecon.utils.cli_errors``).
    """
    return call_cli(_main, argv, prog=PROG)


if __name__ == "__main__":
    sys.exit(main())
