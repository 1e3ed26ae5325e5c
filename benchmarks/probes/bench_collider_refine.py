"""What ``press.collider_refine`` buys and costs on a data preset's touches, both values in one process.

    OMP_NUM_THREADS=1 PYTHONPATH=. python -m benchmarks.probes.bench_collider_refine --preset cls_paper_cpu \
        --classes spoon,screwdriver,scissors,pan,ladle,fork,key,knife,bottle,mug --objects 2 --refine 1,2

Builds the preset's ``train`` dataset once per refine value (no cache; everything else the preset's) and generates
the same objects with each, alternating per object so that both see the same load. Per refine value: the touches
that felt something (the reading's ``contact``: a force at some step), CPU seconds per touch (``time.process_time``,
one torch thread) and per class the touches felt. The ratio is of total CPU seconds against the first refine value,
measured in this process. The set-up alone (frames, footprint rays, the mesh collider whose table the refinement
enlarges) is what ``EIPSimulator.place_batch`` runs; ``benchmarks/speed/bench_gpu.py`` times it apart.
``press.compile`` is the preset's unless overridden (``press.compile=false`` times the eager solver without a compile
in the first object).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from hydra.utils import instantiate

from tvrecon.data.presets import compose_preset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="cls_paper_cpu")
    parser.add_argument("--classes", default="spoon,screwdriver,scissors,pan,ladle,fork,key,knife,bottle,mug")
    parser.add_argument("--objects", type=int, default=2, help="objects per class")
    parser.add_argument("--refine", default="1,2", help="comma-separated press.collider_refine values")
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of the data preset")
    args = parser.parse_args()
    torch.set_num_threads(1)
    classes = args.classes.split(",")
    refines = [int(r) for r in args.refine.split(",")]

    sets = {}
    for r in refines:
        cfg = compose_preset(args.preset, ["cache_dir=null", f"press.collider_refine={r}", *args.overrides])
        dm = instantiate(cfg, _convert_="all")
        n = len(classes) * args.objects
        sets[r] = dm.make_dataset("train", classes=classes, num_objects=n)
    first = sets[refines[0]]
    print(
        f"{args.preset} {' '.join(args.overrides)}: pad {first.sensor.resolution} x {first.sensor.layers} on "
        f"{first.press.n_grid}^3, {first.touches_per_item} touches per object, {len(first)} objects, refine {refines}"
    )
    res = {r: {"cpu": 0.0, "touches": 0, "felt": 0, "per_class": {}} for r in refines}
    for i in range(len(first)):
        cls, _ = first.object_of(i)
        line = f"  {cls:12s}"
        for r in refines:
            c0 = time.process_time()
            raw = sets[r].generate(i)
            cpu = time.process_time() - c0
            felt, m = int(raw["contact"].sum()), len(raw["contact"])
            out = res[r]
            out["cpu"] += cpu
            out["touches"] += m
            out["felt"] += felt
            pc = out["per_class"].setdefault(cls, [0, 0])
            pc[0], pc[1] = pc[0] + felt, pc[1] + m
            line += f" | refine {r}: felt {felt}/{m}, {cpu / m:.3f} CPU-s/touch"
        print(line, flush=True)
    base = res[refines[0]]["cpu"]
    for r in refines:
        o = res[r]
        print(
            f"refine {r}: felt {o['felt']}/{o['touches']}, {o['cpu'] / o['touches']:.3f} CPU-s/touch, "
            f"total CPU / refine {refines[0]}: {o['cpu'] / base:.3f}"
        )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"args": vars(args) | {"out": str(args.out)}, "results": res}, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
