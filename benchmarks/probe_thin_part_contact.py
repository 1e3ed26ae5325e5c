"""Why one paper touch diverges with the particle contact: a mug's handle pressed from the side (cls_paper, val 45).

``generate preset=cls_paper library.protocol=shared_base`` met one touch that blows up at every time step with the
particle contact (``val`` item 45, the ``shared_base`` mug, instance 1, touch 0: the pad from the side onto the
handle); ``GeneratedDataset._simulate_stable`` presses it with the grid contact instead and warns. This probe presses
that touch alone with the particle contact's constants as they are and with the ones given on the command line
(``tvrecon.sim.mpm.particle_contact``: ``ITERATIONS``, the Jacobi passes of the grid-mediated impulse;
``PUSH_CAP_CELLS``, the most a particle found inside is pushed out per step; ``PUSH_OUT``), and prints per variant
whether it pressed, in how many steps, and the pad's largest stretch (largest singular value of F) every 8 steps.

    python benchmarks/probe_thin_part_contact.py                      # the defaults and the two variants below
    python benchmarks/probe_thin_part_contact.py ITERATIONS=2 PUSH_CAP_CELLS=0.02

About 10 CPU-s a variant (the authors' 61 x 61 x 10 pad on the 128 grid, one thread). Nothing is cached.
"""

from __future__ import annotations

import sys
import time

import torch
from hydra.utils import instantiate

import tvrecon.sim.mpm.particle_contact as pc
from tvrecon.data.presets import compose_preset
from tvrecon.data.touches.policies import Touches, sample_touches, simulate_touches
from tvrecon.sim.mpm import MLSMPM

CONSTANTS = ("ITERATIONS", "PUSH_CAP_CELLS", "PUSH_OUT")
ITEM = 45  # cls_paper, shared_base, val split: the mug, instance 1
DEFAULT_VARIANTS = [{}, {"ITERATIONS": 1}, {"PUSH_CAP_CELLS": 0.01}]


def parse(args: list[str]) -> dict[str, float]:
    """``NAME=value`` pairs of the particle contact's constants."""
    out: dict[str, float] = {}
    for a in args:
        name, _, value = a.partition("=")
        if name not in CONSTANTS or not value:
            raise SystemExit(f"expected NAME=value with NAME one of {', '.join(CONSTANTS)}; got {a!r}")
        out[name] = type(getattr(pc, name))(value)
    return out


def press(ds, mesh, touch: Touches, change: dict[str, float]) -> str:  # noqa: ANN001 - a dataset, a trimesh
    """Press ``touch`` with the contact constants changed by ``change``; a line saying what happened."""
    saved = {k: getattr(pc, k) for k in CONSTANTS}
    stretch: list[float] = []
    step = MLSMPM.step

    def traced(self, state, *args, **kwargs):  # noqa: ANN001, ANN202 - MLSMPM.step's own signature
        out = step(self, state, *args, **kwargs)
        stretch.append(float(torch.linalg.svdvals(out.F).max()))
        return out

    MLSMPM.step = traced
    for k, v in change.items():
        setattr(pc, k, v)
    t0 = time.perf_counter()
    try:
        reading = simulate_touches(ds.simulator, mesh, touch, batch_size=1)[0]
        what = f"pressed in {reading.steps} steps, image max {float(reading.image.abs().max()):.2f} cells"
    except FloatingPointError as e:
        what = f"diverged at step {len(stretch)} ({e})"
    finally:
        MLSMPM.step = step
        for k, v in saved.items():
            setattr(pc, k, v)
    name = ", ".join(f"{k}={v}" for k, v in change.items()) or "defaults " + ", ".join(f"{k}={saved[k]}" for k in saved)
    return (
        f"{name}: {what}; {time.perf_counter() - t0:.1f} s\n"
        f"  largest stretch of F every 8 steps: {[round(s, 2) for s in stretch[::8]]}"
    )


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    cfg = compose_preset("cls_paper", ["library.protocol=shared_base", "cache_dir=null"])
    ds = instantiate(cfg, _convert_="all").make_dataset("val")
    cls, instance = ds.object_of(ITEM)
    mesh = ds.mesh(ITEM)
    touches = sample_touches(mesh, ds.touches_per_item, seed=ds.seeds(ITEM)[0], policy=ds.touch, sim=ds.simulator)
    one = touches.take(0)
    direction = [round(float(v), 3) for v in one.directions[0]]
    print(f"cls_paper shared_base val item {ITEM} ({cls}, instance {instance}), touch 0, direction {direction}")
    for change in [parse(argv)] if argv else DEFAULT_VARIANTS:
        print(press(ds, mesh, one, change), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
