"""What a reconstruction run's own numbers say about its touches: the lines ``make demo`` prints after its tables.

:func:`explain_touches` reads one test result (``metrics.json`` of a reconstruction run, see
:mod:`tvrecon.report.tables`) and says, from its numbers: whether the touches moved the answer (no touch against
k touches), whether the model tells its own touches from another object's (``touch_controls``), what refinement
onto the touches' contact patches gave (``refine``); then, from the Table 3 runs under ``results/table3``, what the
paper's fusion model does with Table 1's amount of data, and the command of that full-size run.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from tvrecon.report.paper_numbers import paper_touch_ratio

__all__ = ["explain_touches"]

DEFAULT_RESULTS = Path(__file__).resolve().parents[2] / "results"
PAGE = "docs/reproduce/table3.md"


def _chamfer(result: Mapping[str, Any], mode: str) -> float | None:
    entry = result["modes"].get(mode)
    return None if entry is None else float(entry["chamfer"])


def _touch_counts(modes: Mapping[str, Any], prefix: str) -> list[int]:
    return sorted(int(m[len(prefix) :]) for m in modes if re.fullmatch(re.escape(prefix) + r"\d+", m))


def _pct(a: float, b: float) -> str:
    """``a`` against ``b`` as a signed percentage: ``+4.1%`` when a is 4.1% above b."""
    return f"{100.0 * (a / b - 1.0):+.1f}%"


def _training_split(preset: str) -> str:
    """`` (650 training objects of 35 classes)`` from ``configs/data/<preset>.yaml`` (read as a file: this runs inside
    train.py's Hydra app, where a second Hydra composition is refused); empty when the file does not say."""
    from omegaconf import OmegaConf

    from tvrecon.data.presets import CONFIG_DIR
    from tvrecon.data.shapes.registry import CLASSES

    path = CONFIG_DIR / f"{preset}.yaml"
    train = OmegaConf.to_container(OmegaConf.load(path)).get("train") if path.is_file() else None  # type: ignore[union-attr]
    if not isinstance(train, dict) or not isinstance(train.get("num_samples"), int):
        return ""
    classes = train.get("classes")
    n_classes = len(CLASSES) if classes is None else len(classes)
    return f" ({train['num_samples']} training objects of {n_classes} classes)"


def _paper_size_lines(results_root: Path) -> list[str]:
    """What the Table 3 runs under ``results_root`` say of the paper's fusion model at Table 1's size."""
    from tvrecon.report.results_tables import load_runs

    table3 = results_root / "table3"
    if not table3.is_dir():
        return [f"- The paper's fusion model at Table 1's size: see {PAGE} (its results folder is not here)."]
    runs = [r for r in load_runs(table3) if r.metrics.get("task") == "reconstruction"]
    full = [r for r in runs if r.metrics["name"] == "full" and "tv@10:other" in r.metrics["modes"]]
    precisions = {r.result()["precision"] for r in full}  # Pixel2Mesh trained the way the fusion runs were
    visual = [r for r in runs if r.metrics["name"] == "visual_only" and r.result()["precision"] in precisions]
    if not full or not visual:
        return [f"- The paper's fusion model at Table 1's size: see {PAGE}."]
    own = [_chamfer(r.metrics, "tv@10") or 0.0 for r in full]
    other = [_chamfer(r.metrics, "tv@10:other") or 0.0 for r in full]
    worse = sum(100.0 * (o / w - 1.0) for o, w in zip(other, own)) / len(full)
    vis = sum(_chamfer(r.metrics, "visual") or 0.0 for r in visual) / len(visual)
    ratio = (sum(own) / len(own)) / vis
    m = full[0].manifest
    walls = [float(r.manifest["wall_s"]) for r in full if r.manifest.get("wall_s")]
    preset = m.get("data_preset")
    command = re.sub(r"\bseed=\d+", f"seed={m.get('seed')}", str(m.get("command")))
    size = _training_split(str(preset))
    lines = [
        f"- The paper's fusion reads its touches with Table 1's amount of data: on `{preset}`{size} "
        f"another object's 10 touches score {worse:.1f}% worse than its own (mean of {len(full)} seeds), "
        f"and 10 touches give {ratio:.2f}x Pixel2Mesh's error ({len(visual)} seed{'s' * (len(visual) > 1)}; the paper: "
        f"{paper_touch_ratio():.2f}x). Results: results/table3; page: {PAGE}.",
        f"- The full-size run: `python -m tvrecon.data.generate preset={preset} workers=2`, then `{command}`"
        + (
            f" (about {sum(walls) / len(walls) / 3600:.1f} h a seed there; machine: {m.get('machine')})"
            if walls
            else ""
        )
        + "; the paper's recipe on a GPU: `python train.py experiment=full data=paper trainer=gpu`.",
    ]
    return lines


def explain_touches(result: Mapping[str, Any], results_root: Path | None = DEFAULT_RESULTS) -> str:
    """A few lines on what the touches did in ``result`` (a reconstruction test result), and where the paper's
    fusion model reads them (from ``results_root``'s Table 3 runs; None leaves that part out).

    Raises:
        ValueError: ``result`` is not a reconstruction result with a ``visual`` (no touch) mode.
    """
    if result.get("task") != "reconstruction" or "visual" not in result.get("modes", {}):
        raise ValueError("explain_touches needs a reconstruction result with a 'visual' (no touch) mode")
    modes = result["modes"]
    base = _chamfer(result, "visual") or 0.0
    lines = ["What the touches did in this run (chamfer x1e-3, lower is better):"]
    ks = _touch_counts(modes, "tv@")
    if ks:
        k = max(ks)
        touched = [_chamfer(result, f"tv@{j}") or 0.0 for j in ks]
        verdict = "the touches help" if touched[-1] < base else "with this run's training the touches do not help"
        lines.append(
            f"- No touch {base:.2f}; {' / '.join(map(str, ks))} touches {' / '.join(f'{v:.2f}' for v in touched)}: "
            f"{verdict} ({k} touches {_pct(touched[-1], base)} against none)."
        )
        other = _chamfer(result, f"tv@{k}:other")
        if other is not None:
            reads = (
                "the answer depends on which object was touched (over 5% apart)"
                if other > touched[-1] * 1.05
                else "it does not tell its own touches from another object's (within 5%)"
            )
            lines.append(
                f"- Another object's {k} touches: {other:.2f} against its own {touched[-1]:.2f} "
                f"({_pct(other, touched[-1])}): {reads}."
            )
        refined = [(j, _chamfer(result, f"tv@{j}+refine")) for j in ks]
        refined = [(j, v) for j, v in refined if v is not None]
        if refined:
            j, v = refined[-1]
            lines.append(
                f"- Refined onto the touches' contact patches at test time (`model.refine=true`): "
                f"{' / '.join(f'{x:.2f}' for _, x in refined)} with {' / '.join(str(x) for x, _ in refined)} touches, "
                f"{v / base:.2f}x the no-touch answer with {j}: the touches' geometry helps when it is used directly."
            )
    else:
        lines.append(f"- No touch {base:.2f}; the run tested no mode with touches.")
    if results_root is not None:
        lines += _paper_size_lines(Path(results_root))
    return "\n".join(lines) + "\n"
