"""Validation chamfer per epoch with each checkpoint's stored BatchNorm statistics and with recomputed ones.

    python benchmarks/plot_bn_validation.py --run <train.py run dir> [--run ...] --evals <eval.py output dir> [...]
        --out benchmarks/results/<dir>/bn_validation.png [--csv <file>]

The stored curve is the run's own ``csv/metrics.csv`` (``val/chamfer`` per epoch, as train.py logged it). The
recomputed points are ``eval.py split=val bn_recalibrate_batches=K`` results of the run's epoch checkpoints
(``callbacks.model_checkpoint.save_top_k=-1`` keeps them all), read from every ``metrics.json`` below ``--evals``
that has ``bn_recalibrated``; a checkpoint ``epoch_007.ckpt`` is epoch 7. A validation jump that the recomputed
statistics remove is a statistics mismatch, not a worse network (``tvrecon/train/bn_recalibrate.py``).
"""

from __future__ import annotations

import argparse
import csv
import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def stored_curve(run: Path) -> dict[int, float]:
    """epoch -> val/chamfer logged in training (``<run>/csv/metrics.csv``)."""
    path = run / "csv" / "metrics.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} does not exist: --run takes a train.py run folder trained with logger=csv")
    with path.open() as f:
        return {int(r["epoch"]): float(r["val/chamfer"]) for r in csv.DictReader(f) if r.get("val/chamfer")}


def recomputed_points(evals: list[Path], run: Path) -> dict[str, dict[int, float]]:
    """touches choice -> epoch -> val/chamfer of ``run``'s checkpoints scored with recomputed statistics."""
    out: dict[str, dict[int, float]] = defaultdict(dict)
    name = run.resolve().name
    for root in evals:
        for path in sorted(root.rglob("metrics.json")):
            result = json.loads(path.read_text())
            recal, ckpt = result.get("bn_recalibrated"), str(result.get("checkpoint", ""))
            match = re.search(r"epoch_(\d+)\.ckpt$", ckpt)
            if not recal or match is None or Path(ckpt).resolve().parent.parent.name != name:
                continue
            out[str(recal["touches"])][int(match.group(1))] = float(result["val"]["val/chamfer"])
    return dict(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--run", type=Path, action="append", required=True, help="train.py run folder (repeat)")
    parser.add_argument("--evals", type=Path, action="append", required=True, help="eval.py output folder (repeat)")
    parser.add_argument("--out", type=Path, required=True, help="the figure (.png)")
    parser.add_argument("--csv", type=Path, default=None, help="also write the numbers here")
    args = parser.parse_args(argv)

    fig, axes = plt.subplots(1, len(args.run), figsize=(4.2 * len(args.run), 3.4), squeeze=False)
    rows = [["run", "epoch", "stored", "recomputed_train", "recomputed_max"]]
    for ax, run in zip(axes[0], args.run, strict=True):
        stored = stored_curve(run)
        points = recomputed_points(args.evals, run)
        ax.plot(list(stored), list(stored.values()), "o-", label="stored statistics (train.py's validation)")
        for touches, marker in (("train", "s--"), ("max", "^")):
            pts = dict(sorted(points.get(touches, {}).items()))
            if pts:
                ax.plot(list(pts), list(pts.values()), marker, label=f"recomputed ({touches} touches)")
        ax.set_title(run.name, fontsize=9)
        ax.set_xlabel("epoch")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.set_ylabel("val chamfer x1e-3")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        for epoch in sorted(stored):
            rows.append([run.name, str(epoch), f"{stored[epoch]:.3f}"] + [
                f"{points[t][epoch]:.3f}" if epoch in points.get(t, {}) else "" for t in ("train", "max")
            ])  # fmt: skip
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.stem + ".tmp" + args.out.suffix)
    fig.savefig(tmp, dpi=120)
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    for r in rows:
        print(" | ".join(r))
    if args.csv is not None:
        tmp_csv = args.csv.with_name(args.csv.name + ".tmp")
        with tmp_csv.open("w", newline="") as f:
            csv.writer(f).writerows(rows)
        tmp_csv.replace(args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
