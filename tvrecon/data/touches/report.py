"""Which touches felt nothing: the cached ``contact`` flags of a generated dataset, per class.

A touch reads blank when the pad never met the object, e.g. a part thinner than the grid resolves (a fork's tines
on a 64-cell grid under the paper's touches, :mod:`tvrecon.data.touches.sweep`). The data keeps such a reading (all
zeros, ``contact`` False) and this report says how many there are, so a user sees which classes a grid cannot hold.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tvrecon.data.cache.store import cache_key
from tvrecon.data.dataset_base import GeneratedDataset

__all__ = ["ContactReport", "contact_report"]


@dataclass
class ContactReport:
    """Touches without contact per class, over the cached items of a dataset.

    Attributes:
        missed: class -> touches that felt nothing. total: class -> touches read. items_missing: items not cached.
    """

    missed: dict[str, int] = field(default_factory=dict)
    total: dict[str, int] = field(default_factory=dict)
    items_missing: int = 0

    @property
    def fraction(self) -> float:
        """Touches without contact / touches read, over every class (0 when nothing was read)."""
        total = sum(self.total.values())
        return sum(self.missed.values()) / total if total else 0.0

    def line(self) -> str:
        """One line: the overall share and the classes with misses, most first."""
        worst = sorted(((m, c) for c, m in self.missed.items() if m), reverse=True)
        per = ", ".join(f"{c} {m}/{self.total[c]}" for m, c in worst) or "none"
        return f"touches without contact: {sum(self.missed.values())}/{sum(self.total.values())} ({per})"


def contact_report(dataset: GeneratedDataset) -> ContactReport:
    """Count the touches without contact among the cached items of ``dataset`` (nothing is generated).

    Args:
        dataset: a generated dataset with a cache directory.

    Returns:
        :class:`ContactReport`.
    """
    report = ContactReport()
    for i in range(len(dataset)):
        entry = dataset.cache.load(cache_key(dataset.spec(i)))
        if entry is None or "contact" not in entry:
            report.items_missing += 1
            continue
        cls = dataset.object_of(i)[0]
        contact = np.asarray(entry["contact"], dtype=bool)
        report.missed[cls] = report.missed.get(cls, 0) + int((~contact).sum())
        report.total[cls] = report.total.get(cls, 0) + int(contact.size)
    return report
