"""The paper's own numbers (EIP, ACM MM 2021: Tables 2, 3 and 4), the reference our tables stand beside.

Transcribed from the paper (``paper/eip-paper.tex``, tables ``tabs:classification``, ``tabs:chamfer`` and
``tabs:detialed_compare``); Table 1 (the split sizes) is :data:`tvrecon.data.presets.TABLE1`. Chamfer distances are
x1e-3, accuracies in %.
"""

from __future__ import annotations

__all__ = ["PAPER_TABLE2", "PAPER_TABLE3", "PAPER_TABLE4", "PAPER_TABLE4_CLASSES", "paper_touch_ratio"]

#: Table 2: accuracy (%) of the tactile classifier by number of touches, (mean, std) over three runs.
PAPER_TABLE2: dict[int, tuple[float, float]] = {
    1: (36.7, 2.3),
    2: (47.4, 1.6),
    4: (59.7, 1.1),
    6: (81.5, 0.7),
    8: (90.2, 0.6),
    10: (92.9, 0.3),
}

#: Table 3: chamfer x1e-3 per row; keys ``"visual"``, ``"tactile@k"``, ``"tv@k"`` (the modes of
#: :mod:`tvrecon.report.tables`); a cell the paper leaves empty is absent. "Ours" is the paper's fusion model
#: (``experiment=full``); "Chart-based" is Smith et al. 2020, another method.
PAPER_TABLE3: dict[str, dict[str, float]] = {
    "Chart-based (Smith et al. 2020)": {
        "visual": 13.65,
        "tactile@5": 25.06,
        "tactile@10": 17.44,
        "tv@5": 8.10,
        "tv@10": 5.83,
    },
    "Ours (the paper's fusion model)": {
        "visual": 14.07,
        "tactile@2": 28.70,
        "tactile@5": 21.91,
        "tactile@10": 15.65,
        "tv@2": 10.27,
        "tv@5": 7.22,
        "tv@10": 5.32,
    },
}

#: Table 4's class order (the 10 reconstruction test classes).
PAPER_TABLE4_CLASSES: tuple[str, ...] = (
    "bottle", "bowl", "can", "conditioner", "cube", "fork", "gear", "pepsi", "spoon", "scissors",
)  # fmt: skip

#: Table 4: per-class chamfer x1e-3 with 10 touches (view and touches), then the average, per row; the keys of the
#: ablations are the experiment names of ``configs/experiment``.
PAPER_TABLE4: dict[str, tuple[float, ...]] = {
    "chart_based": (7.02, 6.50, 5.27, 4.31, 5.65, 4.79, 7.45, 5.77, 4.95, 6.62, 5.83),
    "full": (6.23, 7.41, 4.62, 3.57, 4.71, 5.04, 7.13, 4.79, 3.86, 5.82, 5.32),
    "no_gap": (8.75, 11.24, 8.08, 6.30, 6.29, 6.75, 10.74, 6.16, 9.95, 6.47, 8.07),
    "no_direction": (8.12, 9.54, 6.79, 5.01, 6.04, 6.10, 8.61, 6.22, 4.90, 6.30, 6.76),
    "region_1x1": (7.55, 8.18, 6.34, 4.97, 6.18, 4.92, 7.51, 5.77, 3.67, 5.53, 6.06),
    "region_5x5": (6.80, 7.10, 5.66, 5.73, 5.36, 5.17, 8.73, 4.65, 5.36, 6.69, 6.13),
    "single_stage": (6.75, 8.06, 5.38, 4.20, 5.29, 4.91, 8.10, 5.75, 4.74, 6.20, 5.94),
}


def paper_touch_ratio() -> float:
    """The paper's headline gain from touch: its fusion model with 10 touches over Pixel2Mesh (its Visual column),
    5.32 / 14.07 = 0.38."""
    ours = PAPER_TABLE3["Ours (the paper's fusion model)"]
    return ours["tv@10"] / ours["visual"]
