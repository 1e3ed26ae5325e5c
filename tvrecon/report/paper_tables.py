"""The paper's Tables 1-4 with ours beside them: the paper's rows, then our models as mean +- std over their seeds.

Built on the tables of :mod:`tvrecon.report.tables` (row labels, order and modes), :mod:`tvrecon.report.cls_report`
(Table 2 by model) and :mod:`tvrecon.report.seed_summary` (mean +- std cells); the paper's numbers are
:mod:`tvrecon.report.paper_numbers`. A result here is a ``metrics.json`` dict (see :mod:`tvrecon.report.tables`) with
two optional keys the results renderer adds from the run's manifest: ``"epochs"`` and ``"fixed_visual"`` (a
``touch_cascade`` trained on a frozen visual-only run), which split a model's runs into rows.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from tvrecon.report.cls_report import build_table2
from tvrecon.report.method_rows import method_rows, touch_ratio
from tvrecon.report.paper_numbers import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4, PAPER_TABLE4_CLASSES
from tvrecon.report.schedules import common_schedule, schedule_of, schedule_words
from tvrecon.report.seed_summary import mean_std_cell
from tvrecon.report.table_format import (
    CLS_TOUCHES,
    PRETTY_NAMES,
    RECON_TOUCHES,
    Table,
    check_results,
    data_note,
    fmt,
    mean_std,
    ordered_rows,
)
from tvrecon.report.tables import VISUAL_FOOTNOTE, primary_mode

__all__ = ["build_table1", "build_table2_vs_paper", "build_table3_vs_paper", "build_table4_vs_paper", "seed_groups"]


#: Row labels that differ from :data:`PRETTY_NAMES` here, where the paper's own rows also say "Ours".
LABELS: dict[str, str] = {"full": "The paper's fusion model (`full`)"}


def _group_label(
    name: str, epochs: int | None, fixed: bool, precision: str | None, common_epochs: int | None, common_precision: str
) -> str:
    label = LABELS.get(name, PRETTY_NAMES.get(name, name))
    extra = ["visual path fixed"] if fixed else []
    return ", ".join([label, *extra, *schedule_words(epochs, precision, common_epochs, common_precision)])


def seed_groups(results: Iterable[Mapping[str, Any]]) -> list[tuple[str, list[Mapping[str, Any]]]]:
    """Reconstruction results grouped into rows: one per (experiment name, epochs, fixed visual path, training
    precision), in the paper's row order, each with a readable label (the epochs and the precision are named where
    they differ from the most common)."""
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    groups: dict[tuple[str, Any, bool, Any], list[Mapping[str, Any]]] = {}
    for r in recon:
        key = (str(r["name"]), r.get("epochs"), bool(r.get("fixed_visual")), r.get("precision"))
        groups.setdefault(key, []).append(r)
    common, common_precision = common_schedule(recon)
    return [(_group_label(n, e, f, p, common, common_precision), runs) for (n, e, f, p), runs in groups.items()]


def _mean(runs: Sequence[Mapping[str, Any]], mode: str) -> float | None:
    values = [float(r["modes"][mode]["chamfer"]) for r in runs if mode in r["modes"]]
    return sum(values) / len(values) if values and len(values) == len(runs) else None


def _seeds(runs: Sequence[Mapping[str, Any]]) -> str:
    return ", ".join(str(r.get("seed", "?")) for r in runs)


def build_table3_vs_paper(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = RECON_TOUCHES) -> Table:
    """Table 3 with the paper's rows first, then one row per model (mean +- std over its seeds) and the ratio of its
    chamfer with the most touches to Pixel2Mesh's (the paper: its Visual column; ours: the visual-only runs' mean)."""
    results = check_results(results)
    k = max(touches)
    header = ["Model", "Seeds", "Visual"] + [f"Tactile {t}" for t in touches] + [f"T&V {t}" for t in touches]
    header.append(f"T&V {k} / Visual")
    rows: list[list[str]] = []
    layouts: list[str] = []
    for label, cells in PAPER_TABLE3.items():
        row = [f"Paper: {label}", "-", fmt(cells.get("visual"))]
        row += [fmt(cells.get(f"tactile@{t}")) for t in touches] + [fmt(cells.get(f"tv@{t}")) for t in touches]
        row.append(f"{cells[f'tv@{k}'] / cells['visual']:.2f}x")
        rows.append(row)
    groups = seed_groups(results)
    visual = [runs for _, runs in groups if str(runs[0]["name"]) == "visual_only"]
    starred = False
    recon = [r for r in results if r["task"] == "reconstruction"]
    common, common_precision = common_schedule(recon)
    for m in method_rows(recon):  # the paper's two rows on our data, each column from its own experiment
        label = ", ".join([f"On our data: {m.method.label}", *schedule_words(*m.schedule, common, common_precision)])
        row = [label, _seeds(m.tactile_visual or m.tactile)]
        row.append(
            mean_std_cell(m.visual, ["visual"]) + ("*" if m.visual_from_touch_model else "") if m.visual else "-"
        )
        row += [mean_std_cell(m.tactile, [f"tactile@{t}"]) for t in touches]  # "-" where the experiment has no run
        row += [mean_std_cell(m.tactile_visual, [f"tv@{t}"]) for t in touches]
        ratio = touch_ratio(m, k)
        row.append(
            "-" if ratio is None else f"{ratio[0]:.2f}x" + (f" +- {ratio[1]:.2f}" if len(m.tactile_visual) > 1 else "")
        )
        rows.append(row)
        starred |= m.visual_from_touch_model
        layouts.append(
            f"On our data: {m.method.label}: Visual from `{m.method.visual}`"
            + (
                f" (no run: `{m.method.tactile_visual}` with every touch masked out, starred)"
                if m.visual_from_touch_model
                else ""
            )
            + f", Tactile from `{m.method.tactile}`, T&V from `{m.method.tactile_visual}`; T&V {k} / Visual over "
            f"`{m.method.tactile_visual}`'s seeds against the mean Visual."
        )
    for label, runs in groups:
        # Pixel2Mesh trained the same way (epochs, precision) where there is one, else at the most common epochs and
        # the same precision (a model trained on top of a visual-only run: a few epochs of its own), else the first
        same = [v for v in visual if schedule_of(v[0]) == schedule_of(runs[0])]
        same = same or [v for v in visual if schedule_of(v[0]) == (common, runs[0].get("precision"))] or visual
        reference = _mean(same[0], "visual") if same else None
        visual_cell = mean_std_cell(runs, ["visual"])
        if visual_cell != "-" and runs[0].get("modality") == "tactile_visual":
            visual_cell += "*"
            starred = True
        row = [label, _seeds(runs), visual_cell]
        row += [mean_std_cell(runs, [f"tactile@{t}"]) for t in touches]
        row += [mean_std_cell(runs, [f"tv@{t}"]) for t in touches]
        best = _mean(runs, f"tv@{k}")
        row.append(f"{best / reference:.2f}x" if best is not None and reference else "-")
        rows.append(row)
    notes = [
        "Chamfer distance x1e-3 (1,000 points on each surface), lower is better; ours: mean +- sample std over the "
        "seeds listed (one seed: no spread).",
        f"T&V {k} / Visual: the row's chamfer with {k} touches over Pixel2Mesh's (the paper's Visual column; ours: "
        "the mean over the seeds of the visual-only model trained the same way).",
    ]
    notes += list(dict.fromkeys(layouts))
    if results:
        notes.append(data_note([r for r in results if r["task"] == "reconstruction"]))
    if starred:
        notes.append(VISUAL_FOOTNOTE)
    return Table("Table 3: mesh reconstruction, chamfer x1e-3, the paper and ours", header, rows, notes)


def build_table4_vs_paper(results: Iterable[Mapping[str, Any]], classes: Sequence[str] = PAPER_TABLE4_CLASSES) -> Table:
    """Table 4: per-class chamfer with the most touches, the paper's rows first, then ours (the mean over a model's
    seeds per class; the average as mean +- std over the seeds)."""
    header = ["Model", "Seeds"] + list(classes) + ["Average"]
    rows: list[list[str]] = []
    for key, values in PAPER_TABLE4.items():
        label = {"chart_based": "Chart-based (Smith et al. 2020)", "full": "the paper's fusion model"}.get(
            key, PRETTY_NAMES.get(key, key)
        )
        rows.append([f"Paper: {label}", "-"] + [fmt(v) for v in values])
    modes = []
    for label, runs in seed_groups(results):
        mode = primary_mode(runs[0])
        modes.append(f"{label}: {mode}")
        per_run = [{str(c): float(v) for c, v in r["modes"][mode].get("per_class", {}).items()} for r in runs]
        cells = []
        for c in classes:
            values = [pc[c] for pc in per_run if c in pc]
            cells.append(fmt(sum(values) / len(values)) if len(values) == len(per_run) else "-")
        present = [[pc[c] for c in classes if c in pc] for pc in per_run]  # the mean over the classes a run has
        averages = [sum(v) / len(v) for v in present if v]
        if averages and len(averages) == len(per_run):
            mean, std = mean_std(averages)
            average = f"{mean:.2f} +- {std:.2f}" if len(averages) > 1 else fmt(mean)
        else:
            average = "-"
        rows.append([label, _seeds(runs)] + cells + [average])
    notes = [
        "Chamfer x1e-3 per class with the row's most touches (the paper: 10 touches, view and touches); ours: the mean "
        "over the seeds, the average (over the classes present) as mean +- sample std over the seeds.",
        "Mode per row of ours (tv@k = view + k touches; tactile@k = blank view + k touches; visual = no touch): "
        + "; ".join(modes),
    ]
    return Table("Table 4: per-class chamfer x1e-3, the paper and ours", header, rows, notes)


def build_table2_vs_paper(
    results: Iterable[Mapping[str, Any]],
    summary_rows: Sequence[Mapping[str, Any]] = (),
    title: str = "Table 2: tactile classification accuracy (%), the paper and ours",
    touches: Sequence[int] = CLS_TOUCHES,
) -> Table:
    """Table 2 (:func:`tvrecon.report.cls_report.build_table2`) with the paper's row first and, after ours,
    ``summary_rows``: rows of a table whose runs are not kept one by one, each ``{"model": label,
    "accuracy_percent": {"<k>": {"mean", "std", "runs"}}}``."""
    results = [r for r in check_results(results) if r["task"] == "classification"]
    ours = build_table2(results, touches) if results else Table("", ["Model"], [], [])
    paper = ["Paper: tactile classifier (3 runs)"] + [
        f"{PAPER_TABLE2[k][0]:.1f} +- {PAPER_TABLE2[k][1]:.1f}" if k in PAPER_TABLE2 else "-" for k in touches
    ]
    rows = [paper] + ours.rows
    notes = list(ours.notes)
    for s in summary_rows:
        cells = s["accuracy_percent"]
        rows.append(
            [str(s["model"])]
            + [
                f"{cells[str(k)]['mean']:.1f} +- {cells[str(k)]['std']:.1f}" if str(k) in cells else "-"
                for k in touches
            ]
        )
        runs = ", ".join(f"{k}: {cells[str(k)]['runs']}" if str(k) in cells else f"{k}: 0" for k in touches)
        notes.append(f"{s['model']}: runs per column {runs}")
    return Table(title, ["Model"] + [f"{k}-touch" for k in touches], rows, notes)


def build_table1(ours: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> Table:
    """Table 1: split sizes, the paper's (:data:`tvrecon.data.presets.TABLE1`) beside each preset's.

    Args:
        ours: ``{task: {preset: {split: SplitSize}}}`` for ``task`` in ``"classification"``, ``"reconstruction"``.
    """
    from tvrecon.data.presets import TABLE1

    header = ["Task", "Split", "Source", "Classes", "Tactile images", "Views"]
    rows: list[list[str]] = []
    for task, splits in TABLE1.items():
        for split, size in splits.items():
            rows.append([task.capitalize(), split, "Paper", str(size.classes), f"{size.tactile:,}", f"{size.visual:,}"])
            for preset, sizes in ours.get(task, {}).items():
                s = sizes.get(split)
                if s is not None:
                    rows.append(["", "", f"`{preset}`", str(s.classes), f"{s.tactile:,}", f"{s.visual:,}"])
    notes = ["Counts of the generated splits (validation splits, which the paper's Table 1 does not list, left out)."]
    return Table("Table 1: the data, the paper's split sizes and our presets'", header, rows, notes)
