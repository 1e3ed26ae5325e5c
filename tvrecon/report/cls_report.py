"""Per-class accuracy and confusion matrices of the tactile classifiers (Table 2's detail).

Each classification result (``metrics.json`` of :class:`~tvrecon.models.lit_cls.ClassificationModule`) holds, per
touch count k, a confusion matrix (rows: true class, columns: predicted) over the test draws. Here they are summed
over the runs (seeds) of each k:

- :func:`build_per_class_table`: one row per class, accuracy (%) with k touches as mean +- std over the runs;
- :func:`plot_confusion`: a row-normalised confusion matrix as a PNG (the rows are true classes, so the diagonal is
  the per-class accuracy);
- :func:`write_confusion_plots`: the fewest and the most touches evaluated, ``confusion_<k>touch.png``;
- :func:`plot_accuracy_by_touches`: Table 2 as curves, ``accuracy_by_touches.png``;
- :func:`plot_per_class`: with several models, which classes each loses, ``per_class_by_model.png`` (all three written
  by :func:`write_classification_plots`).

:func:`build_table2` is Table 2 itself: accuracy by touch count, one row per model (and one per control it ran).

Runs of different models (experiment names) are kept apart: with more than one model the table's columns and the
file names carry the model's name.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tvrecon.report.table_format import CLS_TOUCHES, PRETTY_NAMES, Table, check_results, data_label, data_note, mean_std
from tvrecon.utils.shape_check import check_shape

__all__ = [
    "build_per_class_table",
    "build_table2",
    "confusion_by_touches",
    "file_stem",
    "plot_accuracy_by_touches",
    "plot_confusion",
    "plot_per_class",
    "write_classification_plots",
    "write_confusion_plots",
]


def _cls(results: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The classification results that carry confusion matrices (older ``metrics.json`` files do not)."""
    return [r for r in check_results(results) if r["task"] == "classification" and r.get("confusion")]


def model_key(result: Mapping[str, Any]) -> str:
    """The model a classification result belongs to: its experiment name, with ``@<K>headings`` when it was asked
    over K > 1 headings (``model.headings``): the same checkpoints asked differently are another row, never a seed."""
    k = int(result.get("headings") or 1)
    return str(result["name"]) + (f"@{k}headings" if k > 1 else "")


def model_label(key: str) -> str:
    """The readable name of a :func:`model_key`: ``"Contact-cloud classifier (...), 8 headings averaged"``."""
    name, _, headings = key.partition("@")
    label = PRETTY_NAMES.get(name, name)
    return label + (f", {headings.removesuffix('headings')} headings averaged" if headings else "")


def _by_model(results: Iterable[Mapping[str, Any]]) -> dict[str, list[Mapping[str, Any]]]:
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in _cls(results):
        groups.setdefault(model_key(r), []).append(r)
    return groups


def confusion_by_touches(results: Iterable[Mapping[str, Any]]) -> dict[int, tuple[np.ndarray, list[str], int]]:
    """Confusion matrices summed over the runs (of one model), per touch count.

    Returns:
        {k: (counts (C, C) int64, class names (C,), number of runs)}.

    Raises:
        ValueError: two runs with the same k disagree on the class names.
    """
    out: dict[int, tuple[np.ndarray, list[str], int]] = {}
    for r in _cls(results):
        names = [str(c) for c in r.get("classes", [])]
        for k, matrix in r["confusion"].items():
            m = np.asarray(matrix, dtype=np.int64)
            check_shape(m, "(C, C)", f"confusion matrix for {k} touches")
            if m.shape[0] != m.shape[1]:
                raise ValueError(f"confusion matrix for {k} touches must be square, got shape {m.shape}")
            run_names = names if len(names) == m.shape[0] else [f"class{i}" for i in range(m.shape[0])]
            if int(k) in out:
                total, known, n = out[int(k)]
                if known != run_names:
                    raise ValueError(f"runs with {k} touches have different classes: {known} vs {run_names}")
                out[int(k)] = (total + m, known, n + 1)
            else:
                out[int(k)] = (m, run_names, 1)
    return dict(sorted(out.items()))


def build_per_class_table(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = CLS_TOUCHES) -> Table:
    """Per-class accuracy (%) by touch count: mean +- sample std over the runs that tested that class with k.

    One column per touch count (and model, when the results hold several)."""
    groups = _by_model(results)
    columns: list[tuple[str, int]] = [
        (name, k)
        for name, runs in groups.items()
        for k in touches
        if any(str(k) in r.get("per_class", {}) for r in runs)
    ]
    classes: list[str] = []
    for name, k in columns:
        for r in groups[name]:
            classes += [c for c in r.get("per_class", {}).get(str(k), {}) if c not in classes]
    rows = []
    for c in classes:
        row = [c]
        for name, k in columns:
            found = [r["per_class"][str(k)] for r in groups[name] if c in r.get("per_class", {}).get(str(k), {})]
            values = [100.0 * float(per_class[c]) for per_class in found]
            if values:
                mean, std = mean_std(values)
                row.append(f"{mean:.1f} +- {std:.1f}")
            else:
                row.append("-")
        rows.append(row)
    several = len(groups) > 1
    header = ["Class"] + [f"{model_label(n)} {k}-touch" if several else f"{k}-touch" for n, k in columns]
    notes = [
        "Accuracy (%) of each class's test draws, mean +- sample std over the runs (seeds) of each touch count; "
        "the confusion matrices summed over those runs are confusion_<k>touch.png."
    ]
    return Table("Table 2 per class: accuracy (%) by touches", header, rows, notes)


def plot_confusion(counts: np.ndarray, names: Sequence[str], path: str | Path, title: str) -> Path:
    """Row-normalised confusion matrix (true class down, predicted across) as a PNG, written atomically.

    Args:
        counts: (C, C) int counts, rows = true class.
        names: (C,) class names.
        path: output ``.png``.
        title: figure title.
    """
    from tvrecon.report.viz import plt
    from tvrecon.utils.atomic import save_and_close

    counts = np.asarray(counts, dtype=np.float64)
    check_shape(counts, "(C, C)", "counts")
    if counts.shape[0] != counts.shape[1] or counts.shape[0] != len(names):
        raise ValueError(f"counts must be (C, C) with C = len(names) = {len(names)}, got {counts.shape}")
    rows = counts.sum(1, keepdims=True)
    share = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    C = len(names)
    fig, ax = plt.subplots(figsize=(2.0 + 0.28 * C, 1.5 + 0.28 * C))
    im = ax.imshow(share, cmap="Blues", vmin=0.0, vmax=1.0)
    ax.set_xticks(range(C), names, rotation=90, fontsize=7)
    ax.set_yticks(range(C), names, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    accuracy = float(np.trace(counts) / max(counts.sum(), 1.0))
    ax.set_title(f"{title}\naccuracy {100 * accuracy:.1f}% over {int(counts.sum())} test draws", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.04, pad=0.02, label="share of the true class")
    return save_and_close(fig, path, dpi=110)


def file_stem(name: str) -> str:
    """A model key as a file-name part: letters, digits, ``-`` and ``_`` only (a fused model's name has spaces)."""
    return re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_-]", "_", name)).strip("_") or "model"


def plot_per_class(results: Iterable[Mapping[str, Any]], path: str | Path, touches: int | None = None) -> Path | None:
    """Which classes each model loses: per-class accuracy (%) with k touches, one bar per model (mean over its runs).

    Only the classes some model gets below 100% are drawn, the worst first (by the lowest model's accuracy).

    Args:
        results: classification results of two or more models (runs of one model are averaged).
        path: output ``.png``.
        touches: k; None = the most touches every model was tested with.

    Returns:
        The path, or None with fewer than two models, no touch count they share, or no class below 100%.
    """
    from tvrecon.report.viz import plt
    from tvrecon.utils.atomic import save_and_close

    groups = _by_model(results)
    if len(groups) < 2:
        return None
    shared = set.intersection(*[{int(k) for r in runs for k in r.get("per_class", {})} for runs in groups.values()])
    k = touches if touches is not None else (max(shared) if shared else None)
    if k is None or k not in shared:
        return None
    acc: dict[str, dict[str, float]] = {}  # model -> class -> mean accuracy (%)
    counted: dict[str, int] = {}  # model -> runs tested with k touches
    for name, runs in groups.items():
        per_run = [r["per_class"][str(k)] for r in runs if str(k) in r.get("per_class", {})]
        classes = {c for pc in per_run for c in pc}
        acc[name] = {c: float(np.mean([100.0 * pc[c] for pc in per_run if c in pc])) for c in classes}
        counted[name] = len(per_run)
    classes = sorted({c for a in acc.values() for c in a}, key=lambda c: min(a.get(c, 100.0) for a in acc.values()))
    classes = [c for c in classes if min(a.get(c, 100.0) for a in acc.values()) < 100.0]
    if not classes:
        return None
    M = len(acc)
    width = 0.8 / M
    fig, ax = plt.subplots(figsize=(2.5 + 0.45 * len(classes) * max(1.0, M / 3), 4.0))
    x = np.arange(len(classes))
    for i, (name, a) in enumerate(acc.items()):
        runs = counted[name]
        label = f"{model_label(name)} ({runs} run{'s' * (runs > 1)})"
        ax.bar(x + (i - (M - 1) / 2) * width, [a.get(c, np.nan) for c in classes], width, label=label, color=f"C{i}")
    ax.set_xticks(x, classes, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel(f"test accuracy with {k} touch{'es' * (k > 1)} (%)")
    ax.set_ylim(0, 105)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: no bar hidden
    ax.set_title(f"Classes some model gets wrong with {k} touches (the others: 100% for every model)", fontsize=9)
    return save_and_close(fig, path, dpi=110)


def write_confusion_plots(results: Iterable[Mapping[str, Any]], out_dir: str | Path) -> list[Path]:
    """``confusion_<k>touch.png`` in ``out_dir`` for the fewest and the most touches evaluated (summed over runs);
    ``confusion_<model>_<k>touch.png`` when the results hold several models."""
    groups = _by_model(results)
    paths = []
    for name, runs in groups.items():
        by_k = confusion_by_touches(runs)
        stem = f"confusion_{file_stem(name)}_" if len(groups) > 1 else "confusion_"
        for k in sorted({min(by_k), max(by_k)}):
            counts, names, n = by_k[k]
            title = f"{model_label(name)}: {k} touch{'es' if k > 1 else ''}, {n} run{'s' if n > 1 else ''}"
            paths.append(plot_confusion(counts, names, Path(out_dir) / f"{stem}{k}touch.png", title))
    return paths


def plot_accuracy_by_touches(results: Iterable[Mapping[str, Any]], path: str | Path) -> Path | None:
    """Table 2 as a picture: accuracy (%) against touches, one line per model (mean over its runs, a band of +- one
    sample std), its 'another object's touches' control dashed in the same colour; None without classification
    results.
    """
    from tvrecon.report.viz import plt
    from tvrecon.utils.atomic import save_and_close

    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in check_results(results):
        if r["task"] == "classification":
            groups.setdefault(model_key(r), []).append(r)
    if not groups:
        return None
    fig, ax = plt.subplots(figsize=(9.0, 4.2))
    chance = None
    for i, (name, runs) in enumerate(groups.items()):
        colour = f"C{i % 10}"
        for key, style in (("accuracy", "-"), ("accuracy_other", "--")):
            ks = sorted({int(k) for r in runs for k in (r.get(key) or {})})
            if not ks:
                continue
            stats = [mean_std([100.0 * float(r[key][str(k)]) for r in runs if str(k) in r.get(key, {})]) for k in ks]
            mean = np.array([m for m, _ in stats])
            std = np.array([s for _, s in stats])
            label = model_label(name) + (" (another object's touches)" if key != "accuracy" else "")
            ax.plot(ks, mean, style, marker="o", color=colour, label=f"{label}, {len(runs)} run{'s' * (len(runs) > 1)}")
            ax.fill_between(ks, mean - std, mean + std, color=colour, alpha=0.15)
        classes = runs[0].get("classes")
        chance = 100.0 / len(classes) if classes else chance
    if chance is not None:
        ax.axhline(chance, color="grey", lw=0.8, ls=":", label=f"chance ({chance:.1f}%)")
    ax.set_xlabel("touches")
    ax.set_ylabel("test accuracy (%)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: no curve hidden
    ax.set_title("Tactile classification by number of touches", fontsize=10)
    return save_and_close(fig, path, dpi=110)


def write_classification_plots(results: Iterable[Mapping[str, Any]], out_dir: str | Path) -> list[Path]:
    """The confusion matrices (:func:`write_confusion_plots`), ``accuracy_by_touches.png``
    (:func:`plot_accuracy_by_touches`) and, with several models, ``per_class_by_model.png`` (:func:`plot_per_class`)
    in ``out_dir``."""
    results = list(results)
    paths = write_confusion_plots(results, out_dir)
    curve = plot_accuracy_by_touches(results, Path(out_dir) / "accuracy_by_touches.png")
    bars = plot_per_class(results, Path(out_dir) / "per_class_by_model.png")  # several models only
    return paths + [p for p in (curve, bars) if p is not None]


def build_table2(results: Iterable[Mapping[str, Any]], touches: Sequence[int] = CLS_TOUCHES) -> Table:
    """Table 2: classification accuracy (%) by number of touches, one row per model (experiment name), mean +- std
    over its runs (seeds).

    Each classification result contributes its accuracy for every touch count it was evaluated with; the std
    is the sample standard deviation (ddof=1) over runs, 0 for a single run; ``n`` runs are reported.
    """
    cls = [r for r in check_results(results) if r["task"] == "classification"]
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for r in cls:  # runs on other touches or another split protocol are other rows, never averaged together
        groups.setdefault((model_key(r), data_label(r)), []).append(r)
    several = len({data for _, data in groups}) > 1
    rows: list[list[str]] = []
    notes = []
    for (name, data), runs in groups.items():
        for key, suffix in (("accuracy", ""), ("accuracy_other", ", another object's touches")):
            if key != "accuracy" and not any(isinstance(r.get(key), Mapping) for r in runs):
                continue
            cells = [model_label(name) + (f" [{data}]" if several else "") + suffix]
            counts = []
            for k in touches:
                values = [100.0 * float(r[key][str(k)]) for r in runs if str(k) in (r.get(key) or {})]
                counts.append(len(values))
                if not values:
                    cells.append("-")
                    continue
                mean, std = mean_std(values)
                cells.append(f"{mean:.1f} +- {std:.1f}")
            rows.append(cells)
            notes.append(f"{cells[0]}: runs per column " + ", ".join(f"{k}: {n}" for k, n in zip(touches, counts)))
    notes.insert(0, "Accuracy (%) over the test split, mean +- sample std over the runs (seeds).")
    notes.insert(1, data_note(cls))
    if any(row[0].endswith("another object's touches") for row in rows):
        notes.insert(
            1,
            "Another object's touches: each test sample classified from the touches of the next sample in its batch "
            "with another label, scored against its own label (model.controls=[other]); chance is 1 / classes.",
        )
    return Table(
        "Table 2: tactile classification accuracy (%)", ["Model"] + [f"{k}-touch" for k in touches], rows, notes
    )
