"""The paper's two methods as Table 3 rows assembled from their experiments, and the touch ratio with its spread."""

from __future__ import annotations

import pytest

from tvrecon.report.method_rows import METHODS, method_rows, touch_ratio


def _run(name: str, modes: dict[str, float], epochs: int | None = 8, precision: str | None = None) -> dict:
    return {
        "task": "reconstruction",
        "name": name,
        "modes": {m: {"chamfer": v} for m, v in modes.items()},
        "epochs": epochs,
        "precision": precision,
    }


def test_columns_come_from_their_experiments_at_the_same_schedule_only() -> None:
    results = [
        _run("visual_only", {"visual": 12.0}),
        _run("visual_only", {"visual": 10.0}, epochs=24),
        _run("tactile_only", {"tactile@10": 16.0}),
        _run("full", {"visual": 13.0, "tv@10": 10.8}),
        _run("full", {"visual": 13.0, "tv@10": 10.0}, epochs=24),
        _run("chart_based", {"visual": 15.0, "tv@10": 9.0}),
    ]
    rows = method_rows(results)
    assert [(r.method.tactile_visual, r.schedule) for r in rows] == [
        ("chart_based", (8, None)),
        ("full", (8, None)),
        ("full", (24, None)),
    ]
    chart, ours8, ours24 = rows
    assert chart.visual_from_touch_model and chart.visual[0]["name"] == "chart_based" and chart.tactile == []
    assert not ours8.visual_from_touch_model and [r["modes"]["visual"]["chamfer"] for r in ours8.visual] == [12.0]
    assert [r["name"] for r in ours8.tactile] == ["tactile_only"] and ours24.tactile == []
    assert ours24.visual[0]["modes"]["visual"]["chamfer"] == 10.0  # the 24-epoch Pixel2Mesh, not the 8-epoch one
    assert touch_ratio(ours8, 10) == pytest.approx((0.9, 0.0))
    assert touch_ratio(chart, 10) == pytest.approx((0.6, 0.0))
    assert touch_ratio(ours8, 5) is None  # no tv@5 in the runs


def test_touch_ratio_spread_is_over_the_touch_models_seeds() -> None:
    results = [_run("visual_only", {"visual": v}) for v in (9.0, 11.0)]  # mean 10
    results += [_run("full", {"visual": 12.0, "tv@10": v}) for v in (8.0, 9.0, 10.0)]
    (ours,) = method_rows(results)
    mean, std = touch_ratio(ours, 10)
    assert mean == pytest.approx(0.9) and std == pytest.approx(0.1)


def test_runs_on_a_fixed_visual_path_and_other_tasks_are_left_out() -> None:
    fixed = _run("full", {"tv@10": 1.0}) | {"fixed_visual": True}
    cls = {"task": "classification", "name": "classify", "accuracy": {}}
    assert method_rows([fixed, cls]) == []
    assert [m.tactile_visual for m in METHODS] == ["chart_based", "full"]


def test_table3_beside_the_paper_gives_each_method_its_row_with_the_ratio_and_its_spread() -> None:
    from tvrecon.report.paper_tables import build_table3_vs_paper

    results = [_run("chart_based_visual", {"visual": 13.0})]
    results += [_run("chart_based", {"visual": 15.0, "tv@2": 9.0, "tv@5": 8.0, "tv@10": v}) for v in (6.5, 7.8)]
    results += [_run("visual_only", {"visual": 12.0}, epochs=24)]
    results += [_run("full", {"visual": 12.5, "tv@2": 11.0, "tv@5": 10.5, "tv@10": 10.8}, epochs=24)]
    for r, seed in zip(results, (42, 42, 43, 42, 42)):
        r |= {"seed": seed, "modality": "visual" if "visual" in r["name"] else "tactile_visual"}
    rows = {r[0]: r[1:] for r in build_table3_vs_paper(results).rows}
    chart = rows["On our data: Chart-based (Smith et al. 2020)"]
    assert chart[:2] == ["42, 43", "13.00"] and chart[5:8] == ["9.00 +- 0.00", "8.00 +- 0.00", "7.15 +- 0.92"]
    assert chart[-1] == "0.55x +- 0.07"  # (6.5 / 13 + 7.8 / 13) / 2, spread over the two seeds
    ours = rows["On our data: The paper's model, 24 epochs"]  # the epochs named where they are not the common 8
    assert ours[1] == "12.00" and ours[-1] == "0.90x"
