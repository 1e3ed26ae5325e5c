"""Paper-preset touches pressed by an earlier commit's simulator and by the working tree, in one process (not a test).

    OMP_NUM_THREADS=1 TORCHINDUCTOR_COMPILE_THREADS=1 python benchmarks/bench_press_ab.py --old REV [--touches 4]
        [--first 1] [--stride 3] [--eager] [--contact grid|particle] [--preset cls_paper] [--per-object 1]

``git archive REV tvrecon`` is unpacked into a temporary folder as the package ``tvrecon_old`` (imports renamed), so
both versions run side by side; each touch (classes ``first + stride * i`` of ``available_classes()``, seeded
cone-policy touch, paper preset: 64x64x6 pad, n_grid 128) is pressed by both, alternating which goes first, on one
thread, with ``compile=True`` unless ``--eager``. Prints per touch the CPU seconds, the old/new ratio and the reading
differences (image in grid cells, relative force; whether the whole reading is bit-identical: :func:`identical`), then
the median and total ratio. ``--per-object N``: each job is N touches of one object, pressed on one mesh object by
``simulate_touches`` (those of one strength in one ``press_batch`` call) as ``generate`` presses an item; CPU-s per
touch, the readings of all N compared.
Used for each step of issue 13
step 3 (benchmarks/README.md); only ratios from one process mean something on a loaded machine. ``--contact`` sets
``PressConfig.contact`` of both (the old revision must know the field). ``--preset NAME`` takes the pad, the press
and the touch policy of that data preset instead (e.g. ``cls_paper``: the authors' 61x61x10 pad, the object at 0.16 of
the domain, the paper's touches through its centre 12% deep), its ``press.compile`` aside.
"""

from __future__ import annotations

import argparse
import importlib
import io
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
import warnings
from pathlib import Path

import torch
import trimesh
from hydra.utils import instantiate
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tvrecon.data.presets import compose_preset  # noqa: E402
from tvrecon.data.shapes.registry import available_classes, make_shape  # noqa: E402
from tvrecon.data.touches.policies import sample_touches, simulate_touches  # noqa: E402
from tvrecon.sim.mpm.state import CONTACT_MODES  # noqa: E402
from tvrecon.sim.press import EIPSimulator, PressConfig  # noqa: E402
from tvrecon.sim.sensor.elastic_pad import SensorConfig  # noqa: E402


def import_old(rev: str, where: Path):
    """``tvrecon.sim.press`` of commit ``rev``, imported as ``tvrecon_old.sim.press``."""
    blob = subprocess.run(["git", "archive", rev, "tvrecon"], cwd=ROOT, check=True, capture_output=True).stdout
    tarfile.open(fileobj=io.BytesIO(blob)).extractall(where, filter="data")
    (where / "tvrecon").rename(where / "tvrecon_old")
    for f in (where / "tvrecon_old").rglob("*.py"):
        f.write_text(re.sub(r"\btvrecon\b(?=[. ])", "tvrecon_old", f.read_text()))
    sys.path.insert(0, str(where))
    import tvrecon_old.sim.press as old_press

    return old_press


def identical(ra, rb) -> bool:
    """Whether two readings are bit-identical: image, force, force_field, position (``torch.equal``), steps, depth and
    chamfer (``==``)."""
    tensors = ("image", "force", "force_field", "position")
    return all(torch.equal(getattr(ra, k), getattr(rb, k)) for k in tensors) and all(
        getattr(ra, k) == getattr(rb, k) for k in ("steps", "depth", "chamfer")
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", required=True, help="git revision to compare with (e.g. HEAD~1)")
    parser.add_argument("--touches", type=int, default=4)
    parser.add_argument("--first", type=int, default=1, help="index of the first class")
    parser.add_argument("--stride", type=int, default=3, help="class index step between touches")
    parser.add_argument("--eager", action="store_true", help="compare the eager paths (default: compile=True)")
    parser.add_argument("--contact", choices=CONTACT_MODES, default=None, help="PressConfig.contact of both")
    parser.add_argument("--preset", default=None, help="a data preset's pad, press and touches (e.g. cls_paper)")
    parser.add_argument("--per-object", type=int, default=1, help="touches of one object per press_batch call")
    args = parser.parse_args()
    torch.set_num_threads(1)
    comp = not args.eager
    with tempfile.TemporaryDirectory() as tmp:
        op = import_old(args.old, Path(tmp))
        kw = {} if args.contact is None else {"contact": args.contact}
        sensor_kw, press_kw, policy = {"resolution": (64, 64), "layers": 6}, {"n_grid": 128, **kw}, None
        if args.preset is not None:
            cfg = compose_preset(args.preset, ["cache_dir=null"])
            sensor_kw = OmegaConf.to_container(cfg.sensor)
            sensor_kw["resolution"] = tuple(sensor_kw["resolution"])
            press_kw = {k: v for k, v in OmegaConf.to_container(cfg.press).items() if k != "compile"} | kw
            policy = instantiate(cfg.touch)
        new = EIPSimulator(SensorConfig(**sensor_kw), PressConfig(**press_kw), compile=comp)
        # SensorConfig left tvrecon.sim.press in the layout of issue 25
        old_pad = importlib.import_module("tvrecon_old.sim.sensor.pad")
        old_sensor = getattr(op, "SensorConfig", None) or old_pad.SensorConfig
        old = op.EIPSimulator(old_sensor(**sensor_kw), op.PressConfig(**press_kw), compile=comp)
        classes = available_classes()
        jobs = []
        n = args.per_object
        for i in range(args.touches):
            name = classes[(args.first + args.stride * i) % len(classes)]
            mesh = make_shape(name, 0)
            jobs.append((name, mesh, sample_touches(mesh, n, seed=i, policy=policy, sim=new)))
        warnings.simplefilter("ignore")

        def fresh(mesh):  # each version's own mesh object: what trimesh caches on it is not shared between them
            return trimesh.Trimesh(vertices=mesh.vertices.copy(), faces=mesh.faces.copy(), process=False)

        for sim in (old, new):  # warm-up (and compile)
            simulate_touches(sim, fresh(jobs[0][1]), jobs[0][2], batch_size=n)
        print(
            f"torch {torch.__version__}, 1 thread, {'compiled' if comp else 'eager'}; old = {args.old}; "
            f"contact {args.contact or 'default'}; pad, press and touches of "
            f"{args.preset or 'the 64x64x6 pad on 128^3 (cone touches)'}"
        )
        ratios, t_old, t_new, differ = [], 0.0, 0.0, 0
        for k, (name, mesh, touches) in enumerate(jobs):
            out = {}
            for which, sim in (("old", old), ("new", new)) if k % 2 == 0 else (("new", new), ("old", old)):
                m = fresh(mesh)
                c0 = time.process_time()
                r = simulate_touches(sim, m, touches, batch_size=n)
                out[which] = ((time.process_time() - c0) / n, r)
            (a, ras), (b, rbs) = out["old"], out["new"]
            ratios.append(a / b)
            t_old, t_new = t_old + a, t_new + b
            di = max((ra.image - rb.image).abs().max().item() for ra, rb in zip(ras, rbs))
            df = max(
                ((ra.force - rb.force).norm() / ra.force.norm().clamp_min(1e-30)).item() for ra, rb in zip(ras, rbs)
            )
            same = all(identical(ra, rb) for ra, rb in zip(ras, rbs))
            differ += int(not same)
            steps = "/".join(f"{ra.steps}" for ra in ras[:3]) + ("..." if n > 3 else "")
            same_steps = all(ra.steps == rb.steps for ra, rb in zip(ras, rbs))
            print(
                f"{name:12s} steps {steps} (same in both: {same_steps}) old {a:5.2f} new {b:5.2f} CPU-s a touch, "
                f"old/new {a / b:5.3f}; max|d image| {di:.2g}, |d force|/|force| {df:.2g}, bit-identical {same}"
            )
        J = len(jobs)
        print(
            f"median old/new {statistics.median(ratios):.3f}, total {t_old / t_new:.3f} "
            f"({t_old / J:.3f} -> {t_new / J:.3f} CPU-s per touch on this machine's load, {n} touches a call); jobs "
            f"not bit-identical: {differ} of {J}"
        )


if __name__ == "__main__":
    main()
