"""Mean +- std over seeds of the reconstruction modes that decide whether touch helps (runs of one experiment and
training schedule with several seeds, e.g. ``train.py -m experiment=touch_geometry seed=42,43``), and the touch
controls at every touch count (:func:`build_controls_over_seeds`).

One row per experiment name and training schedule (:mod:`tvrecon.report.schedules`) with at least two results; columns:
no touch, Tactile & Visual with k touches (Tactile alone for the tactile-only models), the same refined onto the
touches' contact patches, and the touch controls at the most touches (another object's touches, blank images). For the
visual-only model the refined columns are its no-touch prediction refined with k touches (``visual+refine@k``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from tvrecon.report.schedules import common_schedule, schedule_of, schedule_words
from tvrecon.report.table_format import (
    PRETTY_NAMES,
    RECON_TOUCHES,
    Table,
    check_results,
    fmt_mean_std,
    ordered_rows,
)

__all__ = ["build_controls_over_seeds", "build_seed_summary", "mean_std_cell"]


def mean_std_cell(results: Sequence[Mapping[str, Any]], modes: Sequence[str]) -> str:
    """``mean +- std`` of the chamfer in the first of ``modes`` each result has (one result: its value alone, it has no
    spread); ``-`` unless every result has one."""
    values = []
    for r in results:
        mode = next((m for m in modes if m in r["modes"]), None)
        if mode is None:
            return "-"
        values.append(float(r["modes"][mode]["chamfer"]))
    return fmt_mean_std(values) if values else "-"


def _schedule_groups(recon: Sequence[Mapping[str, Any]]) -> list[tuple[str, list[Mapping[str, Any]]]]:
    """Results grouped by experiment name and training schedule (epochs, precision), each group labelled with its
    name and what of its schedule differs from the most common one (``"Visual only (Pixel2Mesh), 24 epochs"``)."""
    groups: dict[tuple[str, Any, Any], list[Mapping[str, Any]]] = {}
    for r in recon:
        groups.setdefault((str(r["name"]), *schedule_of(r)), []).append(r)
    common_epochs, common_precision = common_schedule(recon)
    return [
        (", ".join([PRETTY_NAMES.get(n, n), *schedule_words(e, p, common_epochs, common_precision)]), runs)
        for (n, e, p), runs in groups.items()
    ]


def build_seed_summary(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = RECON_TOUCHES) -> Table:
    """Chamfer (x1e-3) mean +- std over the seeds of every reconstruction experiment run with two or more seeds."""
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    groups = _schedule_groups(recon)
    k_max = max(touches)
    header = (
        ["Model", "Seeds", "No touch"]
        + [f"{k} touches" for k in touches]
        + [f"{k} touches + refinement" for k in touches]
        + [f"Another object's {k_max}", f"Blank {k_max}"]
    )
    rows = []
    for label, runs in groups:
        if len(runs) < 2:
            continue
        seeds = ", ".join(str(r.get("seed", "?")) for r in runs)
        row = [label, seeds, mean_std_cell(runs, ["visual"])]
        row += [mean_std_cell(runs, [f"tv@{k}", f"tactile@{k}"]) for k in touches]
        row += [mean_std_cell(runs, [f"tv@{k}+refine", f"tactile@{k}+refine", f"visual+refine@{k}"]) for k in touches]
        row += [mean_std_cell(runs, [f"tv@{k_max}:{c}", f"tactile@{k_max}:{c}"]) for c in ("other", "blank")]
        rows.append(row)
    notes = [
        "Chamfer x1e-3, mean +- sample std over the seeds ('-' where a seed lacks the mode). No touch: every touch "
        "masked out (for the visual-only model, its only mode). k touches: the view and the first k touches (for a "
        "tactile-only model a blank view and the k touches). + refinement: the prediction pulled onto the k touches' "
        "contact patches at test time (the visual-only model's no-touch prediction). Another object's / "
        f"Blank: the {k_max} touches' content replaced (touch_controls)."
    ]
    return Table("Over seeds: mean +- std", header, rows, notes)


def build_controls_over_seeds(results: Iterable[Mapping[str, Any]]) -> Table:
    """The touch controls at every touch count tested with them: own touches against another object's and blank
    ones, mean +- std over the seeds of each experiment (and training precision), one row per touch count."""
    recon = ordered_rows([r for r in check_results(results) if r["task"] == "reconstruction"])
    groups = _schedule_groups([r for r in recon if not r.get("fixed_visual")])
    header = ["Model", "Seeds", "Touches", "No touch", "Own touches", "Another object's", "Blank"]
    rows = []
    for label, runs in groups:
        bases = [m.split(":")[0] for m in runs[0]["modes"] if m.endswith(":other")]
        bases = [b for b in bases if all(f"{b}:other" in r["modes"] for r in runs)]
        for base in sorted(bases, key=lambda b: int(b.split("@")[1])):
            row = [label, ", ".join(str(r.get("seed", "?")) for r in runs), base.split("@")[1]]
            row += [mean_std_cell(runs, [m]) for m in ("visual", base, f"{base}:other", f"{base}:blank")]
            rows.append(row)
    notes = [
        "Chamfer x1e-3, mean +- sample std over the seeds (one seed: its value). The touches' positions are kept and "
        "their content replaced: another object's tactile images, directions and contact patches (the next sample of "
        "the batch), or blank tactile images and no patch. A model that reads its touches does worse with both than "
        "with its own."
    ]
    return Table("Touch controls at every touch count", header, rows, notes)
