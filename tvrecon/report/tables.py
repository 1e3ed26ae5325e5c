"""The paper's result tables (Tables 2, 3 and 4) built from test metric dicts, as Markdown and CSV.

A *result* is the JSON-serialisable dict a LightningModule writes at the end of ``trainer.test`` (and
``train.py`` / ``eval.py`` save as ``metrics.json``):

Reconstruction (``tvrecon.models.lit_recon.ReconstructionModule.test_results``)::

    {"task": "reconstruction", "name": "full", "modality": "tactile_visual",   # | "visual" | "tactile"
     "modes": {"visual": {"chamfer": 14.1, "count": 50, "per_class": {"bottle": 13.0, ...}, "fscore@...": ...},
               "tv@2": {...}, "tv@5": {...}, "tv@10": {...}}}

Mode keys: ``"visual"`` (no touch: the visual-only model, or a fusion model with every touch masked out),
``"tactile@k"`` (blank view, first k touches), ``"tv@k"`` (view and first k touches), and with ``touch_controls``
``"<mode>:other"`` / ``"<mode>:blank"`` (k touches with another object's or zero tactile content).
Chamfer values are already scaled by 1e3 (the paper's "x 1e-3" unit).

Classification (``tvrecon.models.lit_cls.ClassificationModule.test_results``)::

    {"task": "classification", "name": "classify", "seed": 0, "accuracy": {"1": 0.367, "2": 0.474, ...}}

Table 3 (one row per model): Visual | Tactile 2/5/10 | Tactile & Visual 2/5/10. A fusion model fills its
Visual cell with its own no-touch chamfer (marked ``*``); the visual-only model fills Visual, the tactile-only
model the Tactile columns. When ``full`` and the ``visual_only`` / ``tactile_only`` baselines were all
evaluated, an extra "Ours" row assembles them the way the paper does (Visual from the visual-only model,
Tactile from the tactile-only model, Tactile & Visual from the full model).
Table 4 (one row per model): per-class chamfer with the most touches the model was evaluated with (10) and
the class average. Table 2: classification accuracy (%) by number of touches, mean +- std over runs (seeds).
Touch controls (when a model was tested with ``touch_controls``): own touches against another object's and blank ones.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from tvrecon.data.shapes.registry import RECON_CLASSES
from tvrecon.report.cls_report import build_table2, write_classification_plots
from tvrecon.report.method_rows import method_rows
from tvrecon.report.seed_summary import build_seed_summary
from tvrecon.report.table_format import (
    PRETTY_NAMES,
    RECON_TOUCHES,
    Table,
    check_results,
    data_note,
    fmt,
    ordered_rows,
)
from tvrecon.utils.atomic import atomic_write_text

log = logging.getLogger(__name__)

# re-exported: the tables' public names from one module
__all__ = [
    "data_protocol",
    "build_fscore_table",
    "build_table3",
    "build_table4",
    "build_tables",
    "build_touch_controls",
    "collect_results",
    "format_tables",
    "main",
    "write_tables",
]

DEFAULT_CLASSES: tuple[str, ...] = RECON_CLASSES  # the paper's 10 reconstruction classes, in Table 4's order

VISUAL_FOOTNOTE = "* a model that reads touches (fusion, touch geometry, chart-based) with every touch masked out."


def _label(result: Mapping[str, Any], duplicates: set[str]) -> str:
    name = str(result["name"])
    label = PRETTY_NAMES.get(name, name)
    if name in duplicates and result.get("seed") is not None:
        label += f" (seed {result['seed']})"
    return label


def _chamfer(result: Mapping[str, Any], mode: str) -> float | None:
    entry = result["modes"].get(mode)
    return None if entry is None else float(entry["chamfer"])


def primary_mode(result: Mapping[str, Any]) -> str:
    """The mode used for Table 4: the most touches of the model's own modality (``"visual"`` for visual-only)."""
    modes = result["modes"]
    for prefix in ("tv@", "tactile@"):
        ks = [int(m.split("@")[1]) for m in modes if m.startswith(prefix) and ":" not in m and "+" not in m]
        if ks:
            return f"{prefix}{max(ks)}"
    if "visual" in modes:
        return "visual"
    raise ValueError(f"result {result['name']!r} has no evaluated mode (modes={list(modes)})")


def build_table3(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = RECON_TOUCHES) -> Table:
    """Table 3: mean chamfer (x1e-3) per model for Visual, Tactile k and Tactile & Visual k touches.

    Args:
        results: result dicts (see module docstring); classification results are skipped.
        touches: the touch counts of the Tactile and Tactile & Visual column groups.
    Returns:
        The table; cells a model was not evaluated in are ``-``.
    """
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    header = ["Model", "Visual"] + [f"Tactile {k}" for k in touches] + [f"Tactile & Visual {k}" for k in touches]
    names = [str(r["name"]) for r in recon]
    duplicates = {n for n in names if names.count(n) > 1}
    rows: list[list[str]] = []
    starred = refined = False
    for r in recon:
        visual = _chamfer(r, "visual")
        visual_cell = fmt(visual)
        if visual is not None and r.get("modality") == "tactile_visual":
            visual_cell += "*"
            starred = True
        row = [_label(r, duplicates), visual_cell]
        row += [fmt(_chamfer(r, f"tactile@{k}")) for k in touches]
        row += [fmt(_chamfer(r, f"tv@{k}")) for k in touches]
        rows.append(row)
        if any("+refine" in m for m in r["modes"]):  # test-time touch refinement (eval.py refine=true)
            row = [_label(r, duplicates) + " + touch refinement", "-"]
            row += [fmt(_chamfer(r, f"tactile@{k}+refine")) for k in touches]
            row += [fmt(_chamfer(r, f"tv@{k}+refine") or _chamfer(r, f"visual+refine@{k}")) for k in touches]
            rows.append(row)
            refined = True
    notes = [
        "Chamfer distance x1e-3 (1,000 points sampled on the predicted and ground-truth surfaces), lower is better.",
        data_note(recon),
    ]
    layouts = []
    for m in method_rows(recon):
        if not m.tactile and (m.visual_from_touch_model or not m.visual):
            continue  # no experiment beside the Tactile & Visual one: its own row says it all
        starred |= m.visual_from_touch_model
        visual_from = f"{m.method.tactile_visual}*" if m.visual_from_touch_model else m.method.visual
        row = [m.method.layout_label, _mean_cell(m.visual, "visual") + ("*" if m.visual_from_touch_model else "")]
        row += [_mean_cell(m.tactile, f"tactile@{k}") for k in touches]
        row += [_mean_cell(m.tactile_visual, f"tv@{k}") for k in touches]
        rows.append(row)
        layouts.append(
            f"{m.method.layout_label}: Visual from {visual_from}, Tactile from {m.method.tactile}, "
            f"Tactile & Visual from {m.method.tactile_visual} (the mean over their seeds)."
        )
    notes += list(dict.fromkeys(layouts))
    if refined:
        notes.append(
            "+ touch refinement: the model's prediction pulled smoothly onto the touches' contact patches at test time "
            "(tvrecon/models/refine.py); for the visual-only model its no-touch prediction refined with k touches."
        )
    if starred:
        notes.append(VISUAL_FOOTNOTE)
    return Table("Table 3: mesh reconstruction, chamfer x1e-3", header, rows, notes)


def _mean_cell(runs: Sequence[Mapping[str, Any]], mode: str) -> str:
    """The mean chamfer of ``mode`` over ``runs``; ``-`` unless every run has it."""
    values = [_chamfer(r, mode) for r in runs]
    if not values or None in values:
        return "-"
    return fmt(sum(values) / len(values))  # type: ignore[arg-type]


def build_table4(results: Iterable[Mapping[str, Any]], classes: Sequence[str] | None = None) -> Table:
    """Table 4: per-class chamfer (x1e-3) and class average, one row per model (its :func:`primary_mode`).

    Args:
        results: result dicts; classification results are skipped.
        classes: column order; default the classes found in the results (the paper's 10 first, in its order).
    """
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    if classes is not None:
        cols = [str(c) for c in classes]
    else:  # the classes present, in the paper's order first
        found: list[str] = []
        for r in recon:
            for entry in r["modes"].values():
                found += [str(c) for c in entry.get("per_class", {}) if str(c) not in found]
        cols = [c for c in DEFAULT_CLASSES if c in found] + [c for c in found if c not in DEFAULT_CLASSES]
        cols = cols or list(DEFAULT_CLASSES)
    names = [str(r["name"]) for r in recon]
    duplicates = {n for n in names if names.count(n) > 1}
    rows: list[list[str]] = []
    mode_notes: list[str] = []
    for r in recon:
        mode = primary_mode(r)
        per_class = {str(k): float(v) for k, v in r["modes"][mode].get("per_class", {}).items()}
        values = [per_class.get(c) for c in cols]
        present = [v for v in values if v is not None]
        avg = sum(present) / len(present) if present else None
        label = _label(r, duplicates)
        rows.append([label] + [fmt(v) for v in values] + [fmt(avg)])
        mode_notes.append(f"{label}: {mode}")
    notes = [
        "Chamfer x1e-3 per class; Average is the mean over the classes present ('-' = class not in the test split).",
        "Mode per row (tv@k = view + k touches, tactile@k = blank view + k touches): " + "; ".join(mode_notes),
    ]
    return Table("Table 4: per-class chamfer x1e-3", ["Model"] + cols + ["Average"], rows, notes)


def build_touch_controls(results: Iterable[Mapping[str, Any]]) -> Table:
    """Touch controls: chamfer (x1e-3) with k touches, own vs replaced content (``:other``, ``:blank`` modes of
    ``touch_controls``), one row per model and touch count it was tested with them at."""
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    recon = [r for r in recon if any(":" in m for m in r["modes"])]
    names = [str(r["name"]) for r in recon]
    duplicates = {n for n in names if names.count(n) > 1}
    header = ["Model", "Touches", "No touch", "Own touches", "Another object's touches", "Blank tactile images"]
    rows = []
    for r in recon:
        bases = dict.fromkeys(m.split(":")[0] for m in r["modes"] if ":" in m)  # "tv@k" / "tactile@k" with controls
        for base in sorted(bases, key=lambda b: int(b.split("@")[1])):
            rows.append(
                [_label(r, duplicates), base.split("@")[1], fmt(_chamfer(r, "visual"))]
                + [fmt(_chamfer(r, m)) for m in (base, f"{base}:other", f"{base}:blank")]
            )
    notes = [
        "Chamfer x1e-3 with the touches' positions kept and their content replaced: another object's tactile images "
        "and directions (the next sample of the batch), or zero tactile images. A model that reads its touches does "
        "worse with both than with its own. A model that reads the contact patches (touch geometry) gets the other "
        "object's patches (its surface points), and none for blank images (a blank image is the pad at rest)."
    ]
    return Table("Touch controls: does the model read the touches?", header, rows, notes)


def _fscore(result: Mapping[str, Any], mode: str, key: str) -> float | None:
    entry = result["modes"].get(mode)
    return None if entry is None or key not in entry else 100.0 * float(entry[key])


def build_fscore_table(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = RECON_TOUCHES) -> Table:
    """F-scores (%) at every evaluated threshold, per model and touch count, without and with touch refinement.

    One row per model and touch count k (0 = no touch): the model's own mode with k touches (``visual`` for k = 0 and
    for the visual-only model, ``tv@k`` or ``tactile@k`` otherwise) and its refined mode (``<mode>+refine``, or
    ``visual+refine@k`` for the visual-only model; ``-`` when not evaluated).
    """
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    keys = sorted(
        {k for r in recon for e in r["modes"].values() for k in e if k.startswith("fscore@")},
        key=lambda k: float(k.split("@")[1]),
    )
    names = [str(r["name"]) for r in recon]
    duplicates = {n for n in names if names.count(n) > 1}
    taus = [k.split("@")[1] for k in keys]
    header = ["Model", "Touches"] + [f"F@{t}" for t in taus] + [f"F@{t} + touch refinement" for t in taus]
    rows: list[list[str]] = []
    for r in recon:
        modes = r["modes"]
        prefix = next((p for p in ("tv@", "tactile@") if any(m.startswith(p) for m in modes)), None)
        for k in [0, *touches]:
            if k == 0 or prefix is None:
                base, refined = "visual", (None if k == 0 else f"visual+refine@{k}")
            else:
                base, refined = f"{prefix}{k}", f"{prefix}{k}+refine"
            if base not in modes or (prefix is None and k > 0 and refined not in modes):
                continue
            row = [_label(r, duplicates), str(k)] + [fmt(_fscore(r, base, key), 1) for key in keys]
            row += [fmt(None if refined is None else _fscore(r, refined, key), 1) for key in keys]
            rows.append(row)
    notes = [
        "F-score (%) at distance thresholds tau (objects have max extent 1; Pixel2Mesh uses tau and 2 tau), higher "
        "is better; 1,000 points sampled on each surface. Touches 0: the model with no touch input (for the "
        "visual-only model the refinement rows pull its prediction onto k touches' contact patches)."
    ]
    return Table("F-score by touches, without and with touch refinement", header, rows, notes)


def build_tables(results: Iterable[Mapping[str, Any]], classes: Sequence[str] | None = None) -> dict[str, Table]:
    """The tables the results allow: ``table3``/``table4`` for reconstruction, ``table2`` for classification."""
    results = check_results(results)
    tables: dict[str, Table] = {}
    if any(r["task"] == "reconstruction" for r in results):
        tables["table3"] = build_table3(results)
        tables["table4"] = build_table4(results, classes)
        if any(
            k.startswith("fscore@")
            for r in results
            if r["task"] == "reconstruction"
            for e in r["modes"].values()
            for k in e
        ):
            tables["fscore"] = build_fscore_table(results)
        if any(":" in m for r in results if r["task"] == "reconstruction" for m in r["modes"]):
            tables["touch_controls"] = build_touch_controls(results)

        seeds = build_seed_summary(results)
        if seeds.rows:
            tables["seeds"] = seeds
    if any(r["task"] == "classification" for r in results):
        tables["table2"] = build_table2(results)
        from tvrecon.report.cls_report import build_per_class_table  # imports this module

        per_class = build_per_class_table(results)
        if per_class.rows:
            tables["table2_per_class"] = per_class
    return tables


def write_tables(tables: Mapping[str, Table], out_dir: str | Path) -> list[Path]:
    """Write every table as ``<key>.md`` and ``<key>.csv`` plus ``tables.md`` (all of them) into ``out_dir``."""
    out_dir = Path(out_dir)
    written: list[Path] = []
    for key, table in tables.items():
        written.append(atomic_write_text(out_dir / f"{key}.md", table.to_markdown()))
        written.append(atomic_write_text(out_dir / f"{key}.csv", table.to_csv()))
    written.append(atomic_write_text(out_dir / "tables.md", format_tables(tables)))
    return written


def format_tables(tables: Mapping[str, Table]) -> str:
    """All tables as one Markdown text (Table 2, then 3, then 4, then the touch controls)."""
    order = ["table2", "table2_per_class", "table3", "seeds", "table4", "fscore", "touch_controls"]
    keys = [k for k in order if k in tables] + [k for k in tables if k not in order]
    return "\n".join(tables[k].to_markdown() for k in keys)


def data_protocol(data_cfg: Mapping[str, Any]) -> dict[str, str]:
    """What a run's data config says of its touches and split: ``{"touch": <policy class name>, "split": <library
    protocol>}`` (a data config without a ``touch`` block uses the default cone policy, without ``library.protocol``
    the ``unseen`` split)."""
    touch = data_cfg.get("touch") or {}
    target = str(touch.get("_target_", "ConeTouchPolicy")) if isinstance(touch, Mapping) else "ConeTouchPolicy"
    library = data_cfg.get("library") or {}
    split = str(library.get("protocol", "unseen")) if isinstance(library, Mapping) else "unseen"
    return {"touch": target.rpartition(".")[2], "split": split}


def collect_results(paths: Iterable[str | Path]) -> list[dict[str, Any]]:
    """Load every ``metrics.json`` at or below ``paths`` (files or folders), in sorted path order.

    Raises:
        FileNotFoundError: a path does not exist, or no ``metrics.json`` was found at all.
        ValueError: no file is valid JSON (each is named); a bad file among good ones is skipped with a warning
            (a run killed while writing it must not stop the tables of the others, as eval.py skips a bad run).
    """
    import json

    files: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():
            raise FileNotFoundError(f"{p} does not exist (give run folders of train.py/eval.py or metrics.json files)")
        files.extend([p] if p.is_file() else sorted(p.rglob("metrics.json")))
    if not files:
        raise FileNotFoundError(
            f"no metrics.json below {[str(p) for p in paths]}: train.py (test=true) and eval.py write one per run"
        )
    results = []
    bad = []
    for f in files:
        try:
            result = json.loads(f.read_text())
            if isinstance(result, dict) and "data_protocol" not in result:  # a run from before it was recorded
                cfg = f.parent / ".hydra" / "config.yaml"
                if cfg.is_file():
                    from omegaconf import OmegaConf

                    result["data_protocol"] = data_protocol(OmegaConf.load(cfg).get("data") or {})
            results.append(result)
        except (json.JSONDecodeError, UnicodeDecodeError) as err:  # e.g. truncated by a killed run: skip that run
            log.warning("skipping %s: it is not valid JSON (%s); re-run eval.py on its checkpoint", f, err)
            bad.append(str(f))
    if not results:
        raise ValueError(f"{', '.join(bad)} is not valid JSON (truncated?): re-run eval.py on its checkpoint")
    return results


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m tvrecon.report.tables DIR_OR_FILE... [--out DIR]``: the tables of runs already tested, no
    re-evaluation."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m tvrecon.report.tables", description=main.__doc__)
    parser.add_argument("paths", nargs="+", help="run folders (searched recursively for metrics.json) or files")
    parser.add_argument(
        "--out", default=None, help="also write table{2,3,4}.{md,csv}, tables.md (and classifiers' confusion PNGs) here"
    )
    args = parser.parse_args(argv)
    try:
        tables = build_tables(collect_results(args.paths))
    except (FileNotFoundError, ValueError) as err:
        parser.error(str(err))
    if not tables:
        parser.error("the metrics.json files hold no reconstruction or classification results")
    print(format_tables(tables))
    if args.out:
        print(f"(tables written to {write_tables(tables, args.out)[0].parent})")
        for path in write_classification_plots(collect_results(args.paths), args.out):
            print(f"(plot: {path})")
    return 0


if __name__ == "__main__":
    from tvrecon.utils.cli_errors import run_cli

    run_cli(main, prog="python -m tvrecon.report.tables")  # errors: one line, exit 2/1/130
