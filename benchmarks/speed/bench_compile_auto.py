"""What ``compile="auto"`` costs and saves: ``python -m tvrecon.data.generate`` eager and compiled, cold and warm
compile cache, at two job sizes; the break-even it implies and what auto chooses for the whole preset (not a test).

    python -m benchmarks.speed.bench_compile_auto [--preset small] [--items 3 8] [--out results.json] [--compiled-only]
        [--set KEY=VALUE ...]

Five ``generate`` processes, one worker each (one torch thread), every one on an empty data cache so that every item
is simulated: eager with ``--items`` A and B objects; compiled with A objects on an empty compile cache (cold), then
A and B objects on that cache (warm). Per run: CPU seconds of the process (user + sys), wall seconds, and the count of
graphs dynamo compiled (the same count at A and B objects: no recompiles after the first objects). From them:

- marginal CPU-s per touch, eager and compiled: (run B - run A) / (B - A) touches;
- the compile's fixed cost, cold and warm: a compiled run's CPU-s minus an eager run of the same touches, plus the
  touches' saving; and the break-even touches (fixed cost / saving per touch) that ``AUTO_MIN_TOUCHES_*`` round
  (``tvrecon/sim/mpm/compiled/policy.py``).

``--set`` adds data-config overrides to every run (e.g. the old paper pad: ``--set sensor=paper --set press=paper
--set touch=cone --set '~touch.order'``). ``--compiled-only`` runs the three compiled processes alone and prints
the compiled marginal CPU-s per touch (the eager runs of the authors' pad cost ~10 CPU-s a touch).

Ratios from one invocation are comparable; absolute seconds depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks._common import ROOT

CHILD = """
import json, sys, torch
from tvrecon.data import generate
stats = generate.main(sys.argv[1:])
from torch._dynamo.utils import counters
print("BENCH " + json.dumps({"touches": sum(s.touches for s in stats), "seconds": sum(s.seconds for s in stats),
    "graphs": int(counters["stats"]["unique_graphs"])}), flush=True)
"""


def run(
    preset: str, items: int, compile_: str, inductor_dir: str, env: dict[str, str], extra: tuple[str, ...] = ()
) -> dict:
    """One generate process on a fresh data cache (``extra``: more overrides): its CPU-s, wall-s, touches and compiled
    graphs."""
    with tempfile.TemporaryDirectory(prefix="bench_auto_data_") as data:
        argv = [
            f"preset={preset}", "splits=train", "workers=1", f"train.num_samples={items}",
            f"cache_dir={data}", f"compile={compile_}", *extra,
        ]  # fmt: skip
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-c", CHILD, *argv],
            env={**env, "TORCHINDUCTOR_CACHE_DIR": inductor_dir},
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise SystemExit(f"generate failed ({compile_}, {items} items):\n{out.stderr[-3000:]}")
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("BENCH "))
    res = json.loads(line[6:])
    res.update(
        cpu_s=(after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        wall_s=wall,
        items=items,
        compile=compile_,
    )
    return res


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="small", help="data preset (configs/data)")
    parser.add_argument("--items", type=int, nargs=2, default=(3, 8), metavar=("A", "B"), help="objects per run")
    parser.add_argument("--out", type=Path, default=None, help="write the runs and figures as JSON")
    parser.add_argument("--compiled-only", action="store_true", help="skip the eager runs")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a data-config override")
    args = parser.parse_args()
    a, b = args.items
    env = {**os.environ, "PROJECT_ROOT": str(ROOT), "OMP_NUM_THREADS": "1", "TORCHINDUCTOR_COMPILE_THREADS": "1"}
    runs: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="bench_auto_inductor_") as ind:
        for name, items, mode in (
            ("eager_a", a, "false"),
            ("cold_a", a, "true"),
            ("warm_a", a, "true"),
            ("eager_b", b, "false"),
            ("warm_b", b, "true"),
        ):
            if args.compiled_only and mode == "false":
                continue
            runs[name] = r = run(args.preset, items, mode, ind, env, tuple(args.set))
            print(
                f"{name:8s} {r['items']:3d} objects {r['touches']:4d} touches: {r['cpu_s']:7.1f} CPU-s "
                f"{r['wall_s']:7.1f} s wall, {r['graphs']} graphs",
                flush=True,
            )
    if args.compiled_only:
        ta, tb = runs["warm_a"]["touches"], runs["warm_b"]["touches"]
        comp = (runs["warm_b"]["cpu_s"] - runs["warm_a"]["cpu_s"]) / (tb - ta)
        recompiles = runs["warm_b"]["graphs"] - runs["warm_a"]["graphs"]
        print(f"\n{args.preset}: marginal {comp:.3f} CPU-s per touch compiled; {recompiles} recompiles after {a} items")
        if args.out:
            figures = {"compiled_cpu_s_per_touch": comp, "recompiles_after_first_objects": recompiles}
            args.out.write_text(json.dumps({"preset": args.preset, "runs": runs, "figures": figures}, indent=1))
        return
    ta, tb = runs["eager_a"]["touches"], runs["eager_b"]["touches"]
    eager = (runs["eager_b"]["cpu_s"] - runs["eager_a"]["cpu_s"]) / (tb - ta)
    comp = (runs["warm_b"]["cpu_s"] - runs["warm_a"]["cpu_s"]) / (tb - ta)
    saving = eager - comp
    fixed_warm = runs["warm_a"]["cpu_s"] - runs["eager_a"]["cpu_s"] + ta * saving
    fixed_cold = runs["cold_a"]["cpu_s"] - runs["eager_a"]["cpu_s"] + ta * saving
    figures = {
        "eager_cpu_s_per_touch": eager,
        "compiled_cpu_s_per_touch": comp,
        "compiled_over_eager": comp / eager,
        "compile_cpu_s_cold": fixed_cold,
        "compile_cpu_s_warm": fixed_warm,
        "break_even_touches_cold": fixed_cold / saving if saving > 0 else float("inf"),
        "break_even_touches_warm": fixed_warm / saving if saving > 0 else float("inf"),
        "recompiles_after_first_objects": runs["warm_b"]["graphs"] - runs["warm_a"]["graphs"],
    }
    print(
        f"\n{args.preset}: marginal {eager:.3f} CPU-s per touch eager, {comp:.3f} compiled ({comp / eager:.2f}x); "
        f"compile {fixed_cold:.1f} CPU-s cold, {fixed_warm:.1f} warm; break-even "
        f"{figures['break_even_touches_cold']:.0f} touches cold, {figures['break_even_touches_warm']:.0f} warm; "
        f"graphs {runs['warm_a']['graphs']} at {a} objects, {runs['warm_b']['graphs']} at {b}"
    )
    from hydra.utils import instantiate

    from tvrecon.data.presets import compose_preset
    from tvrecon.sim.mpm.compiled.policy import AUTO_MIN_TOUCHES_COLD, AUTO_MIN_TOUCHES_WARM

    dm = instantiate(compose_preset(args.preset, ["cache_dir=null"]), _convert_="all")
    per_worker = {s: len(dm.make_dataset(s)) * dm.make_dataset(s).touches_per_item for s in dm.available_splits()}
    print(
        f"auto compiles a process of >= {AUTO_MIN_TOUCHES_COLD} touches ({AUTO_MIN_TOUCHES_WARM} with a warm cache); "
        f"the preset's splits with workers=1: {per_worker}"
    )
    if args.out:
        args.out.write_text(json.dumps({"preset": args.preset, "runs": runs, "figures": figures}, indent=1))


if __name__ == "__main__":
    main()
