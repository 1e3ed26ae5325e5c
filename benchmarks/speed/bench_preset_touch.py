"""CPU cost of one generated touch of a data preset, measured through the dataset itself (not a test).

    OMP_NUM_THREADS=1 PYTHONPATH=. python -m benchmarks.speed.bench_preset_touch --preset cls_paper_cpu --touches 4 \
        --classes bottle,fork,gear,mug,scissors [hydra overrides, e.g. sensor.resolution=[48,48]]

Builds the preset's ``train`` dataset (no cache) with ``touches_per_object=--touches`` over ``--classes`` and times
``generate(i)`` for one object of each class: touch sampling, placement (and its re-draws), the batched press and
the readings, exactly what ``python -m tvrecon.data.generate`` does per item, on one torch thread. Prints CPU
seconds per touch (``time.process_time``; wall time is printed too but means little on a shared machine) and the
extrapolated CPU time of the whole preset. The override ``press.compile=true`` times the compiled solver; its compile
time is reported apart (``--warmup 1`` generates one extra object first and leaves it out of the per-touch cost).
"""

from __future__ import annotations

import argparse
import time

import torch
from hydra.utils import instantiate

from tvrecon.data.presets import compose_preset, split_sizes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="cls_paper_cpu")
    parser.add_argument("--touches", type=int, default=4, help="touches per object (one press_batch call)")
    parser.add_argument("--classes", default="bottle,fork,gear,mug,scissors")
    parser.add_argument("--warmup", type=int, default=0, help="objects generated first and not counted")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides of the data preset")
    args = parser.parse_args()
    torch.set_num_threads(1)

    cfg = compose_preset(args.preset, ["cache_dir=null", *args.overrides])
    classes = args.classes.split(",")
    dm = instantiate(cfg, _convert_="all")
    n_obj = len(classes) * (1 + args.warmup)
    ds = dm.make_dataset("train", classes=classes, num_objects=n_obj, touches_per_object=args.touches)
    sensor, press = ds.sensor, ds.press
    print(
        f"{args.preset} {' '.join(args.overrides)}: pad {sensor.resolution[0]}x{sensor.resolution[1]}x{sensor.layers}"
        f" on {press.n_grid}^3, {args.touches} touches per object, classes {classes}, torch {torch.__version__}"
    )

    warm = len(classes) * args.warmup
    if warm:
        w0, c0 = time.perf_counter(), time.process_time()
        for i in range(warm):
            ds.generate(i)
        print(
            f"warm-up ({warm} objects, incl. any compile): wall {time.perf_counter() - w0:.1f} s, "
            f"CPU {time.process_time() - c0:.1f} s"
        )
    per = []
    w0, c0 = time.perf_counter(), time.process_time()
    for i in range(warm, warm + len(classes)):
        c1 = time.process_time()
        raw = ds.generate(i)
        per.append((time.process_time() - c1) / args.touches)
        cls, _ = ds.object_of(i)
        print(
            f"  {cls:12s} {per[-1]:.3f} CPU-s/touch, contact {int(raw['contact'].sum())}/{args.touches}, "
            f"max normal {float(raw['tactile'][:, 2].max()):.2f} cells, "
            f"depth mean {raw['depth'].mean():.2f} max {raw['depth'].max():.2f} cells"
        )
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n = len(classes) * args.touches
    total = sum(s.tactile for s in split_sizes(cfg).values())
    sizes = {k: v.tactile for k, v in split_sizes(cfg).items()}
    print(
        f"{n} touches: CPU {cpu:.1f} s ({cpu / n:.3f} CPU-s/touch, per class min {min(per):.3f} max {max(per):.3f}),"
        f" wall {wall:.1f} s"
    )
    print(
        f"preset {sizes} = {total} touches: {total * cpu / n / 60:.0f} CPU-min, "
        f"{total * cpu / n / 2 / 60:.0f} min on 2 workers"
    )


if __name__ == "__main__":
    main()
