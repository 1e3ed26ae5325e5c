"""The speed suite at a small size, written to ONE JSON file keyed by machine, torch version and commit.

    python -m benchmarks.run                       # what ``make bench`` runs: results/bench/suite/<key>/metrics.json
    python -m benchmarks.run --only bench_sim --threads 2 --out /tmp/bench

Each entry of ``SUITE`` is a script of ``benchmarks/speed/`` run as its own process (``python -m
benchmarks.speed.<name> <args>``, from the repository root, ``OMP_NUM_THREADS`` set to ``--threads``), small enough
that the suite takes a few CPU-minutes. The file holds, per script: the command, its exit status, wall seconds, the
lines it printed and, for scripts that write JSON (``--out``), that JSON. The key (``machine``, ``torch``, ``commit``)
names the run folder, so runs on other machines or commits sit beside each other; ratios inside one script's run are
the figures to compare (absolute seconds drift on a shared machine). Beside ``metrics.json`` the folder gets the
``manifest.json`` every results run has (command, data_preset, seed, commit, machine, wall_s, date).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from benchmarks._common import ROOT
from tvrecon.report.provenance import git_commit, machine
from tvrecon.utils.atomic import atomic_write_text

SUITE: dict[str, list[str]] = {
    # the solver against the straightforward dense-grid reference, one process
    "bench_sim": ["--steps", "20", "--repeats", "1"],
    # one press and T touches one at a time against one batched loop
    "bench_press": ["--touches", "2", "--resolution", "32", "--repeats", "1"],
    # press throughput against batch size, the solver scene as a press (eager)
    "bench_gpu": ["--scenes", "bench", "--modes", "eager", "--batches", "1,2", "--count-batch", "0"],
    # one training step of the reconstruction model against the reference graph conv and chamfer
    "bench_train_step": ["--repeats", "1"],
}
JSON_OUT = {"bench_gpu"}  # scripts with ``--out FILE.json``
THREADED = {"bench_sim", "bench_press", "bench_gpu", "bench_train_step"}  # scripts with ``--threads``


def commit() -> str | None:
    """The short commit of the work tree, ``-dirty`` when it has changes; None outside a git checkout."""
    return git_commit(ROOT)


def key(info: dict) -> str:
    """A folder name from the machine, torch version and commit: ``[A-Za-z0-9._-]`` only."""
    raw = f"{info['machine']}_torch-{info['torch']}_{info['commit'] or 'nocommit'}"
    return re.sub(r"[^A-Za-z0-9._-]+", "-", raw).strip("-")


def run_script(name: str, args: list[str], threads: int, tmp: Path) -> dict:
    """Run ``benchmarks/speed/<name>.py`` as a module; its command, status, wall seconds, output and JSON."""
    if not (ROOT / "benchmarks" / "speed" / f"{name}.py").is_file():
        raise ValueError(f"no benchmarks/speed/{name}.py: name a script of the speed suite")
    cmd = [sys.executable, "-m", f"benchmarks.speed.{name}", *args]
    if name in THREADED:
        cmd += ["--threads", str(threads)]
    out = tmp / f"{name}.json"
    if name in JSON_OUT:
        cmd += ["--out", str(out)]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    record = {
        "command": " ".join(["python", *cmd[1:]]).replace(str(out), "<json>"),
        "returncode": proc.returncode,
        "wall_s": round(wall, 2),
        "stdout": proc.stdout.splitlines(),
    }
    if proc.returncode != 0:
        record["stderr_tail"] = proc.stderr.splitlines()[-20:]
    if name in JSON_OUT and out.is_file():
        record["json"] = json.loads(out.read_text())
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=ROOT / "results" / "bench" / "suite",
        help="suite folder; the run goes to <out>/<key>/",
    )
    parser.add_argument("--threads", type=int, default=1, help="torch / OpenMP threads of every script")
    parser.add_argument("--only", nargs="*", default=None, help="run these scripts of the suite only")
    args = parser.parse_args(argv)
    names = list(SUITE) if not args.only else args.only
    unknown = [n for n in names if n not in SUITE]
    if unknown:
        print(f"--only: {unknown} are not in the suite; choose from {list(SUITE)}", file=sys.stderr)
        return 2
    if args.threads < 1:
        print("--threads must be >= 1", file=sys.stderr)
        return 2
    info = {
        "machine": machine(),
        "torch": torch.__version__,
        "commit": commit(),
        "python": platform.python_version(),
        "threads": args.threads,
        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
    }
    runs = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            print(f"{name} ...", flush=True)
            runs[name] = run_script(name, SUITE[name], args.threads, Path(tmp))
            r = runs[name]
            print("\n".join(f"  {line}" for line in r["stdout"][-6:]), flush=True)
            print(f"  -> exit {r['returncode']}, {r['wall_s']} s", flush=True)
    folder = args.out / key(info)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {
        "command": " ".join(["python -m benchmarks.run", *(argv if argv is not None else sys.argv[1:])]),
        "data_preset": None,
        "seed": None,
        "commit": info["commit"],
        "machine": info["machine"],
        "wall_s": round(time.perf_counter() - t0, 1),
        "date": info["date"][:10],
    }
    atomic_write_text(folder / "metrics.json", json.dumps({**info, "runs": runs}, indent=1) + "\n")
    atomic_write_text(folder / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    print(f"wrote {folder.relative_to(ROOT) if folder.is_relative_to(ROOT) else folder}/metrics.json")
    return 0 if all(r["returncode"] == 0 for r in runs.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
