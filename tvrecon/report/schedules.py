"""A result's training schedule, ``(epochs, precision)``: how the tables name it and compare one experiment's schedules.

A reconstruction result carries ``epochs`` (the command's ``trainer.max_epochs``) and ``precision`` (the training
precision) where the results renderer adds them from the run's manifest
(:meth:`tvrecon.report.results_tables.Run.result`); runs of one experiment at another schedule are rows apart in every
table, named by what differs from the most common schedule (``"24 epochs"``, ``"bf16-mixed"``).
:func:`build_schedule_comparison` lays the schedules of each experiment trained at more than one number of epochs side
by side: what the longer schedule buys, and what it costs.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from tvrecon.report.table_format import PRETTY_NAMES, Table, check_results, fmt_mean_std, ordered_rows

__all__ = ["build_schedule_comparison", "common_schedule", "schedule_of", "schedule_words"]

Result = Mapping[str, Any]


def schedule_of(result: Result) -> tuple[int | None, str | None]:
    """``(epochs, precision)`` of a result, None where it does not say."""
    return result.get("epochs"), result.get("precision")


def common_schedule(results: Sequence[Result]) -> tuple[int | None, str]:
    """The most common epochs (None where no result says) and training precision (``32-true`` where none says)."""
    epochs = [r.get("epochs") for r in results if r.get("epochs") is not None]
    common = max(set(epochs), key=epochs.count) if epochs else None
    precisions = [str(r.get("precision")) for r in results if r.get("precision") is not None]
    return common, max(set(precisions), key=precisions.count) if precisions else "32-true"


def schedule_words(
    epochs: int | None, precision: str | None, common_epochs: int | None, common_precision: str | None
) -> list[str]:
    """The epochs and the precision of a row where they differ from the most common ones (``["24 epochs"]``)."""
    words = []
    if epochs is not None and epochs != common_epochs:
        words.append(f"{epochs} epochs")
    if precision is not None and precision != common_precision:
        words.append(precision)
    return words


def _chamfers(runs: Sequence[Result], mode: str) -> list[float] | None:
    values = [float(r["modes"][mode]["chamfer"]) for r in runs if mode in r["modes"]]
    return values if values and len(values) == len(runs) else None


def _cell(values: Sequence[float] | None) -> str:
    return "-" if values is None else fmt_mean_std(values)


def build_schedule_comparison(results: Iterable[Result], touches: int = 10) -> Table:
    """Each reconstruction experiment trained at two or more numbers of epochs (same precision, visual path not
    fixed), one row per number of epochs: the chamfer without touches and with ``touches`` touches (Tactile alone for
    a tactile-only model), its ratio to the visual-only model at the same schedule, and the wall time of a run
    (``wall_s`` of the manifest, where the result has it).

    Shapes: ``results`` are ``metrics.json`` dicts with ``epochs``, ``precision`` and ``wall_s`` added (see module).
    """
    recon = ordered_rows(
        [r for r in check_results(results) if r["task"] == "reconstruction" and not r.get("fixed_visual")]
    )
    groups: dict[tuple[str, Any], dict[Any, list[Result]]] = {}
    for r in recon:
        epochs, precision = schedule_of(r)
        if epochs is not None:
            groups.setdefault((str(r["name"]), precision), {}).setdefault(epochs, []).append(r)
    _, common_precision = common_schedule(recon)
    header = ["Model", "Epochs", "Seeds", "No touch", f"{touches} touches", f"{touches} touches / Visual"]
    header.append("Minutes a run")
    rows = []
    for (name, precision), by_epochs in groups.items():
        if len(by_epochs) < 2:
            continue
        label = ", ".join([PRETTY_NAMES.get(name, name), *schedule_words(None, precision, None, common_precision)])
        for epochs in sorted(by_epochs):
            runs = by_epochs[epochs]
            touched = _chamfers(runs, f"tv@{touches}") or _chamfers(runs, f"tactile@{touches}")
            visual = groups.get(("visual_only", precision), {}).get(epochs)
            reference = _chamfers(visual, "visual") if visual else None
            ratio = "-"
            if touched is not None and reference is not None:
                ratio = f"{(sum(touched) / len(touched)) / (sum(reference) / len(reference)):.2f}x"
            walls = [float(r["wall_s"]) / 60 for r in runs if r.get("wall_s") is not None]
            minutes = fmt_mean_std(walls, digits=0) if walls and len(walls) == len(runs) else "-"
            seeds = ", ".join(str(r.get("seed", "?")) for r in runs)
            rows.append([label, str(epochs), seeds, _cell(_chamfers(runs, "visual")), _cell(touched), ratio, minutes])
    notes = [
        f"Chamfer x1e-3, mean +- sample std over the seeds (one seed: its value). {touches} touches / Visual: over the "
        "visual-only model's mean at the same number of epochs. The learning rate anneals to zero over each run's "
        "epochs (cosine), so a longer run is a different schedule, not the shorter one continued.",
        "Minutes a run: the whole run (training, validation each epoch, the test with the touch controls) as its "
        "manifest records it; the runs of a row may come from different machines, thread counts and training steps "
        "(see `results/bench/train_step`).",
    ]
    return Table(f"Training schedules: {touches} touches at each number of epochs", header, rows, notes)
