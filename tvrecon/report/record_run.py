"""Record a finished training run under ``results/``: its ``metrics.json`` (and ``loss_curves.png``) copied beside
the ``manifest.json`` every results run has, read off the run's own files.

    python -m tvrecon.report.record_run <run dir> results/table3/<name> [--note TEXT] [--machine TEXT]

From the run folder (train.py's output folder, ``hydra.run.dir``):

- ``.hydra/overrides.yaml``: the command, ``python train.py`` and its overrides without the ones that only place
  files (``paths.*``, ``hydra.*``, a resume's ``ckpt_path``);
- ``.hydra/hydra.yaml``: the data preset (the ``data`` choice) and the folder the run started in, whose commit it
  names (:func:`tvrecon.report.provenance.git_commit`);
- ``.hydra/config.yaml``: the seed and the training precision (``trainer.precision`` resolved on this machine: record
  a run on the machine that trained it, or give ``--machine`` and check the precision);
- ``train.log``: the wall time, its first to its last time stamp (test included; ``--wall-s`` where a resumed run's
  log spans a pause).

Bad input (no metrics, no Hydra folder, a results folder that exists without ``--force``) exits 2 and writes nothing;
the folder is written whole or not at all (a temporary folder, then a rename).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import shlex
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from tvrecon.models.precision import register_precision_resolver
from tvrecon.report.provenance import git_commit, machine

__all__ = ["build_manifest", "main", "record_run"]

_PLACING = ("paths.", "hydra.", "ckpt_path=", "+paths.", "++paths.")
_STAMP = re.compile(r"^\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),\d+\]", re.M)


class RecordError(ValueError):
    """A run folder that cannot be recorded; the message says what is missing."""


def _wall_s(log: Path) -> int | None:
    """Seconds from the first to the last time stamp of a Hydra job log; None without two stamps."""
    if not log.is_file():
        return None
    stamps = _STAMP.findall(log.read_text(errors="replace"))
    if len(stamps) < 2:
        return None
    first, last = (dt.datetime.strptime(s, "%Y-%m-%d %H:%M:%S") for s in (stamps[0], stamps[-1]))
    return int((last - first).total_seconds())


def build_manifest(
    run_dir: Path, machine_name: str | None = None, note: str | None = None, wall_s: int | None = None
) -> dict[str, Any]:
    """The ``manifest.json`` of the run in ``run_dir`` (see the module doc).

    Raises:
        RecordError: ``run_dir`` has no ``.hydra`` folder with its three files.
    """
    hydra_dir = run_dir / ".hydra"
    files = {name: hydra_dir / f"{name}.yaml" for name in ("overrides", "hydra", "config")}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise RecordError(f"{run_dir} is not a train.py run folder: missing {', '.join(missing)}")
    overrides = [str(o) for o in OmegaConf.load(files["overrides"])]
    kept = [o for o in overrides if not o.lstrip("~").startswith(_PLACING)]
    hydra_cfg = OmegaConf.load(files["hydra"]).hydra
    cfg = OmegaConf.load(files["config"])
    register_precision_resolver()
    precision = OmegaConf.select(cfg, "trainer.precision", throw_on_resolution_failure=False)  # None: unresolvable
    manifest: dict[str, Any] = {
        "command": " ".join(["python train.py", *(shlex.quote(o) for o in kept)]),
        "data_preset": OmegaConf.select(hydra_cfg, "runtime.choices.data"),
        "seed": OmegaConf.select(cfg, "seed"),
        "commit": git_commit(OmegaConf.select(hydra_cfg, "runtime.cwd") or run_dir),
        "machine": machine_name or machine(),
        "wall_s": wall_s if wall_s is not None else _wall_s(run_dir / "train.log"),
        "date": dt.date.today().isoformat(),
        "precision": None if precision is None else str(precision),
    }
    if note:
        manifest["note"] = note
    return manifest


def record_run(run_dir: Path, out: Path, force: bool = False, **manifest_args: Any) -> Path:
    """Write ``out/`` (``metrics.json``, ``loss_curves.png`` where the run has one, ``manifest.json``) from the run
    in ``run_dir``; returns ``out``.

    Raises:
        RecordError: the run has no ``metrics.json`` (it did not finish its test) or is no train.py run folder, or
            ``out`` exists and ``force`` is False.
    """
    metrics = run_dir / "metrics.json"
    if not metrics.is_file():
        raise RecordError(f"{metrics} does not exist: the run has not finished its test (train.py writes it last)")
    try:
        json.loads(metrics.read_text())
    except json.JSONDecodeError as err:
        raise RecordError(f"{metrics} is not valid JSON ({err})") from None
    if out.exists() and not force:
        raise RecordError(f"{out} exists: pass --force to replace it")
    manifest = build_manifest(run_dir, **manifest_args)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        shutil.copy2(metrics, tmp / "metrics.json")
        if (run_dir / "loss_curves.png").is_file():
            shutil.copy2(run_dir / "loss_curves.png", tmp / "loss_curves.png")
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Record a finished train.py run under results/ (see the module doc)."""
    parser = argparse.ArgumentParser(prog="python -m tvrecon.report.record_run", description=main.__doc__)
    parser.add_argument("run_dir", type=Path, help="the run's output folder (train.py's hydra.run.dir)")
    parser.add_argument("out", type=Path, help="the results folder to write, e.g. results/table3/full_s42")
    parser.add_argument("--machine", help="the machine that trained it (default: this one, tvrecon.report.provenance)")
    parser.add_argument("--note", help="a sentence on how the run was made (e.g. two runs side by side)")
    parser.add_argument("--wall-s", type=int, help="seconds the run took (default: from its train.log)")
    parser.add_argument("--force", action="store_true", help="replace an existing results folder")
    args = parser.parse_args(argv)
    try:
        out = record_run(
            args.run_dir, args.out, args.force, machine_name=args.machine, note=args.note, wall_s=args.wall_s
        )
    except RecordError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"recorded {args.run_dir} -> {out}: render the docs' tables with python -m tvrecon.report.results_tables")
    return 0


if __name__ == "__main__":
    sys.exit(main())
