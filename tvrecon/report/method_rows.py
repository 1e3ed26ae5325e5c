"""The two methods of the paper's Table 3 as rows assembled from the experiments that answer their columns.

The paper's Table 3 gives each method one row: Visual, Tactile k and Tactile & Visual k touches. Here each column
comes from its own experiment, trained the same way (the same epochs and training precision):

- Chart-based (Smith et al. 2020): ``chart_based_visual`` (Visual), ``chart_based_tactile`` (Tactile),
  ``chart_based`` (Tactile & Visual);
- the paper's model: ``visual_only`` (Visual, Pixel2Mesh), ``tactile_only`` (Tactile), ``full`` (Tactile & Visual).

Where a method's visual-only experiment has no run, its Visual column is the Tactile & Visual model's own answer
with every touch masked out (``visual_from_touch_model``: the tables star it). ``touch_ratio`` is the paper's
headline, the error with k touches over the method's Visual error, with its spread over the Tactile & Visual seeds.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tvrecon.report.schedules import schedule_of
from tvrecon.report.table_format import check_results, mean_std

__all__ = ["METHODS", "Method", "MethodRow", "method_rows", "touch_ratio"]

Result = Mapping[str, Any]


@dataclass(frozen=True)
class Method:
    """A method of the paper's Table 3 and the experiment names that answer its three column groups; ``label`` names it
    beside the paper's row, ``layout_label`` in eval.py's table beside each experiment's own row."""

    label: str
    layout_label: str
    visual: str
    tactile: str
    tactile_visual: str


METHODS: tuple[Method, ...] = (
    Method(
        "Chart-based (Smith et al. 2020)",
        "Chart-based (paper layout)",
        "chart_based_visual",
        "chart_based_tactile",
        "chart_based",
    ),
    Method("The paper's model", "Ours (paper layout)", "visual_only", "tactile_only", "full"),
)


@dataclass(frozen=True)
class MethodRow:
    """One method's runs at one schedule: ``schedule`` = (epochs, precision) as the results carry them (None where
    a result does not say), each column group's runs (empty where its experiment has no run)."""

    method: Method
    schedule: tuple[Any, Any]
    visual: list[Result]
    tactile: list[Result]
    tactile_visual: list[Result]
    visual_from_touch_model: bool


def _chamfer(result: Result, mode: str) -> float | None:
    entry = result["modes"].get(mode)
    return None if entry is None else float(entry["chamfer"])


def method_rows(results: Iterable[Result], methods: Sequence[Method] = METHODS) -> list[MethodRow]:
    """One :class:`MethodRow` per method and schedule at which its Tactile & Visual or Tactile experiment has runs
    (reconstruction results only; runs with a fixed visual path are left out), in ``methods`` order."""
    recon = [r for r in check_results(results) if r["task"] == "reconstruction" and not r.get("fixed_visual")]
    by_key: dict[tuple[str, tuple[Any, Any]], list[Result]] = {}
    for r in recon:
        by_key.setdefault((str(r["name"]), schedule_of(r)), []).append(r)
    rows = []
    for method in methods:
        schedules = [s for (n, s) in by_key if n in (method.tactile_visual, method.tactile)]
        for schedule in dict.fromkeys(schedules):  # first-seen order, once each
            tv = by_key.get((method.tactile_visual, schedule), [])
            visual = by_key.get((method.visual, schedule), [])
            borrowed = not visual and any(_chamfer(r, "visual") is not None for r in tv)
            rows.append(
                MethodRow(
                    method,
                    schedule,
                    visual if visual else (tv if borrowed else []),
                    by_key.get((method.tactile, schedule), []),
                    tv,
                    borrowed,
                )
            )
    return rows


def touch_ratio(row: MethodRow, touches: int) -> tuple[float, float] | None:
    """The row's Tactile & Visual chamfer with ``touches`` touches over its Visual chamfer: (mean, sample std) over
    the Tactile & Visual seeds, each divided by the mean Visual chamfer; None where either is missing."""
    visual = [_chamfer(r, "visual") for r in row.visual]
    tv = [_chamfer(r, f"tv@{touches}") for r in row.tactile_visual]
    if not visual or not tv or None in visual or None in tv:
        return None
    reference = sum(visual) / len(visual)  # type: ignore[arg-type]
    return mean_std([v / reference for v in tv])  # type: ignore[operator]
