"""Result tables as text: the :class:`Table` type, mean +- std and the row labels shared by the paper's tables.

Used by :mod:`tvrecon.report.tables` (Tables 3 and 4, the reconstruction tables), :mod:`tvrecon.report.cls_report`
(Table 2 and the classification detail) and :mod:`tvrecon.report.seed_summary`. The result dicts they read are described
in :mod:`tvrecon.report.tables`.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "CLS_TOUCHES",
    "PRETTY_NAMES",
    "Table",
    "check_results",
    "data_label",
    "data_note",
    "fmt",
    "fmt_mean_std",
    "mean_std",
]

#: Touch policies by the short name the tables give them (``data_protocol.touch`` of a result).
TOUCH_NAMES: dict[str, str] = {
    "PaperSweepTouchPolicy": "the paper's touches (centre aim, side-to-top sweep)",
    "ConeTouchPolicy": "cone touches (random surface points)",
}


def data_label(result: Mapping[str, Any]) -> str:
    """``"<touch policy>, <split protocol> split"`` of a result's ``data_protocol`` (train.py / eval.py record it;
    :func:`tvrecon.report.tables.collect_results` fills it from a run's ``.hydra/config.yaml``), ``"data not recorded"``
    without one."""
    dp = result.get("data_protocol")
    if not isinstance(dp, Mapping):
        return "data not recorded"
    touch = str(dp.get("touch", "?"))
    return f"{TOUCH_NAMES.get(touch, touch)}, {dp.get('split', '?')} split"


def data_note(results: Iterable[Mapping[str, Any]]) -> str:
    """One caption line naming the touches and the split protocol of the results (each distinct pair once)."""
    labels = sorted({data_label(r) for r in results})
    return "Data: " + "; ".join(labels) + "."


CLS_TOUCHES: tuple[int, ...] = (1, 2, 4, 6, 8, 10)

# Row labels of the paper for the experiment names of configs/experiment (unknown names are shown as they are).
PRETTY_NAMES: dict[str, str] = {
    "full": "Ours",
    "visual_only": "Visual only (Pixel2Mesh)",
    "tactile_only": "Tactile only",
    "no_gap": "W/o GAP",
    "no_direction": "W/o tactile direction",
    "region_1x1": "1x1 per-pixel fusion",
    "region_5x5": "5x5 per-pixel fusion",
    "single_stage": "Single-stage fusion",
    "touch_depth": "Ours + touch depth (extension)",
    "full_precise_bn": "Ours, precise BatchNorm statistics (beyond the paper)",
    "visual_only_precise_bn": "Visual only, precise BatchNorm statistics (beyond the paper)",
    "touch_geometry": "Touch geometry (beyond the paper)",
    "touch_geometry_no_rim": "Touch geometry, patches without their rim (beyond the paper)",
    "touch_geometry_view_pass": "Touch geometry, a view-alone pass on every sample (beyond the paper)",
    "touch_residual": "Touch geometry as a correction of Pixel2Mesh (beyond the paper)",
    "touch_cascade": "Touch geometry on the Pixel2Mesh answer (beyond the paper)",
    "chart_based": "Chart-based (Smith et al. 2020)",
    "chart_based_predicted": "Chart-based, touch charts predicted from the tactile images",
    "chart_based_visual": "Chart-based, visual only",
    "chart_based_tactile": "Chart-based, tactile only",
    "smoke": "Ours (smoke, tiny data)",
    "classify": "Tactile classifier",
    "classify_paper_cpu": "Tactile classifier",
    "classify_paper_cpu_upsampled": "Tactile classifier, images upsampled to 112 px",
    "classify_touch_set": "Touch-set classifier (beyond the paper)",
    "classify_contact_cloud": "Contact-cloud classifier (beyond the paper)",
    "classify_contact_point": "Contact points only (control)",
    "classify_contact_cloud_images": "Contact cloud + tactile images (beyond the paper)",
    "classify_contact_patches": "Contact cloud + patch tokens (beyond the paper)",
}


@dataclass
class Table:
    """A titled table of strings, printable as Markdown and writable as CSV."""

    title: str
    header: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)

    def to_markdown(self, compact: bool = False) -> str:
        """GitHub-flavoured Markdown: ``### title``, the table, then notes as lines; ``compact`` leaves the cells
        unpadded (for pages, where the rendered table lines the columns up)."""
        widths = [max(len(str(c)) for c in col) for col in zip(self.header, *self.rows)] if self.rows else None
        if widths is None:
            widths = [len(h) for h in self.header]
        if compact:
            widths = [1] * len(widths)

        def line(cells: Sequence[str]) -> str:
            return "| " + " | ".join(str(c).ljust(w) for c, w in zip(cells, widths)) + " |"

        out = [f"### {self.title}", "", line(self.header), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
        out += [line(r) for r in self.rows]
        if not self.rows:
            out.append("(no results)")
        if self.notes:
            out.append("")
            out += self.notes
        return "\n".join(out) + "\n"

    def to_csv(self) -> str:
        """CSV text: header row then data rows (notes are not included)."""
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(self.header)
        writer.writerows(self.rows)
        return buf.getvalue()


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1; 0 for a single value) of a non-empty sequence."""
    if not values:
        raise ValueError("mean_std needs at least one value")
    mean = sum(values) / len(values)
    std = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1)) if len(values) > 1 else 0.0
    return mean, std


def fmt_mean_std(values: Sequence[float], digits: int = 2) -> str:
    """``"mean +- std"`` of a non-empty sequence with ``digits`` decimals; one value alone (it has no spread)."""
    mean, std = mean_std(values)
    return f"{mean:.{digits}f} +- {std:.{digits}f}" if len(values) > 1 else f"{mean:.{digits}f}"


def fmt(value: float | None, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals; ``-`` for None (a mode not evaluated), ``nan`` for NaN (a run that
    diverged: evaluated, and its result is no number)."""
    if value is None:
        return "-"
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    return f"{value:.{digits}f}"


def check_results(results: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    out = list(results)
    for r in out:
        if not isinstance(r, Mapping) or "task" not in r or "name" not in r:
            raise ValueError(
                f"each result must be a mapping with keys 'task' and 'name' (a metrics.json written by "
                f"train.py/eval.py), got {r!r:.200}"
            )
        if r["task"] == "reconstruction" and not isinstance(r.get("modes"), Mapping):
            raise ValueError(
                f"reconstruction result {r['name']!r} needs a 'modes' mapping, got {r.get('modes')!r:.200}"
            )
        if r["task"] == "classification" and not isinstance(r.get("accuracy"), Mapping):
            raise ValueError(
                f"classification result {r['name']!r} needs an 'accuracy' mapping, got {r.get('accuracy')!r:.200}"
            )
    return out


#: touch counts of Tables 3 and 4 (the paper's)
RECON_TOUCHES: tuple[int, ...] = (2, 5, 10)

# Row order of Tables 3 and 4 (paper order), unknown names after these in input order.
ROW_ORDER: tuple[str, ...] = (
    "chart_based",  # the paper's Table 3 lists the Chart-based method first
    "chart_based_predicted",
    "chart_based_visual",
    "chart_based_tactile",
    "visual_only",
    "tactile_only",
    "full",
    "no_gap",
    "no_direction",
    "region_1x1",
    "region_5x5",
    "single_stage",
    "touch_depth",
    "touch_geometry",
    "touch_residual",
    "touch_cascade",
    "smoke",
)


def ordered_rows(results: list[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """Results in the paper's row order (``ROW_ORDER``), unknown names after them in input order."""

    def key(item: tuple[int, Mapping[str, Any]]) -> tuple[int, int]:
        idx, r = item
        name = str(r["name"])
        return (ROW_ORDER.index(name) if name in ROW_ORDER else len(ROW_ORDER), idx)

    return [r for _, r in sorted(enumerate(results), key=key)]
