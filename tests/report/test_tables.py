"""Table builder (paper Tables 2, 3, 4) against hand-made metric dicts."""

from __future__ import annotations

import csv
import io

import pytest

from tvrecon.report.cls_report import build_table2
from tvrecon.report.tables import build_table3, build_table4, build_tables, format_tables, write_tables


def _recon(name: str, modality: str, modes: dict[str, float], per_class: dict[str, float] | None = None) -> dict:
    return {
        "task": "reconstruction",
        "name": name,
        "modality": modality,
        "modes": {m: {"chamfer": v, "count": 4, "per_class": per_class or {}} for m, v in modes.items()},
    }


FULL = _recon(
    "full", "tactile_visual", {"visual": 14.07, "tv@2": 10.27, "tv@5": 7.22, "tv@10": 5.32}, {"bottle": 6.0, "can": 4.0}
)
VIS = _recon("visual_only", "visual", {"visual": 13.5}, {"bottle": 15.0, "can": 11.0})
TAC = _recon("tactile_only", "tactile", {"tactile@2": 28.7, "tactile@5": 21.91, "tactile@10": 15.65}, {"can": 15.0})


def _csv_rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def test_table3_columns_rows_and_paper_layout_row() -> None:
    table = build_table3([FULL, TAC, VIS])
    rows = _csv_rows(table.to_csv())
    assert rows[0] == [
        "Model", "Visual", "Tactile 2", "Tactile 5", "Tactile 10",
        "Tactile & Visual 2", "Tactile & Visual 5", "Tactile & Visual 10",
    ]  # fmt: skip
    # paper order: visual_only, tactile_only, full, then the assembled row
    assert [r[0] for r in rows[1:]] == ["Visual only (Pixel2Mesh)", "Tactile only", "Ours", "Ours (paper layout)"]
    assert rows[1][1:] == ["13.50", "-", "-", "-", "-", "-", "-"]
    assert rows[2][1:] == ["-", "28.70", "21.91", "15.65", "-", "-", "-"]
    assert rows[3][1:] == ["14.07*", "-", "-", "-", "10.27", "7.22", "5.32"]
    assert rows[4][1:] == ["13.50", "28.70", "21.91", "15.65", "10.27", "7.22", "5.32"]
    md = table.to_markdown()
    assert "masked out" in md and md.startswith("### Table 3")


def test_table4_per_class_average_and_primary_mode() -> None:
    table = build_table4([FULL, VIS, TAC])
    rows = _csv_rows(table.to_csv())
    assert rows[0] == ["Model", "bottle", "can", "Average"]  # only the classes present, paper order
    by_label = {r[0]: r[1:] for r in rows[1:]}
    assert by_label["Ours"] == ["6.00", "4.00", "5.00"]
    assert by_label["Visual only (Pixel2Mesh)"] == ["15.00", "11.00", "13.00"]
    assert by_label["Tactile only"] == ["-", "15.00", "15.00"]
    assert "Ours: tv@10" in table.to_markdown() and "Tactile only: tactile@10" in table.to_markdown()


def test_table4_explicit_classes_keep_missing_as_dash() -> None:
    table = build_table4([FULL], classes=["bottle", "bowl", "can"])
    assert _csv_rows(table.to_csv())[1] == ["Ours", "6.00", "-", "4.00", "5.00"]


def test_table2_mean_std_over_seeds() -> None:
    results = [
        {"task": "classification", "name": "classify", "seed": s, "accuracy": {"1": a1, "10": a10}}
        for s, a1, a10 in [(0, 0.30, 0.90), (1, 0.40, 0.94), (2, 0.35, 0.92)]
    ]
    rows = _csv_rows(build_table2(results).to_csv())
    assert rows[0] == ["Model", "1-touch", "2-touch", "4-touch", "6-touch", "8-touch", "10-touch"]
    # mean 35.0, sample std 5.0 ; mean 92.0, std 2.0
    assert rows[1] == ["Tactile classifier", "35.0 +- 5.0", "-", "-", "-", "-", "92.0 +- 2.0"]
    other = {"task": "classification", "name": "classify_touch_set", "seed": 0, "accuracy": {"1": 0.5}}
    rows = _csv_rows(build_table2([*results, other]).to_csv())  # one row per model, never pooled
    assert (
        rows[1][1] == "35.0 +- 5.0"
        and rows[2] == ["Touch-set classifier (beyond the paper)", "50.0 +- 0.0"] + ["-"] * 5
    )


def test_table2_control_row_follows_its_model() -> None:
    """Runs with the 'other' control get a second row right below their model's; models without it get none."""
    cloud = [
        {
            "task": "classification",
            "name": "classify_contact_cloud",
            "seed": s,
            "accuracy": {"10": a},
            "accuracy_other": {"10": o},
        }
        for s, a, o in [(0, 0.80, 0.02), (1, 0.90, 0.04)]
    ]
    paper = {"task": "classification", "name": "classify", "seed": 0, "accuracy": {"10": 0.3}}
    table = build_table2([paper, *cloud])
    rows = _csv_rows(table.to_csv())
    assert [r[0] for r in rows[1:]] == [
        "Tactile classifier",
        "Contact-cloud classifier (beyond the paper)",
        "Contact-cloud classifier (beyond the paper), another object's touches",
    ]
    # mean 85.0, std 7.07; mean 3.0, std 1.41
    assert rows[2][-1] == "85.0 +- 7.1" and rows[3][-1] == "3.0 +- 1.4" and rows[3][1] == "-"
    assert any("another label" in note for note in table.notes)


def test_build_tables_selects_by_task_and_writes_files(tmp_path) -> None:
    cls = {"task": "classification", "name": "classify", "seed": 0, "accuracy": {"2": 0.5}}
    tables = build_tables([FULL, cls])
    assert sorted(tables) == ["table2", "table3", "table4"]
    paths = write_tables(tables, tmp_path)
    names = sorted(p.name for p in paths)
    assert names == ["table2.csv", "table2.md", "table3.csv", "table3.md", "table4.csv", "table4.md", "tables.md"]
    text = (tmp_path / "tables.md").read_text()
    assert text == format_tables(tables)
    assert text.index("Table 2") < text.index("Table 3") < text.index("Table 4")
    assert not list(tmp_path.glob("*.tmp"))
    assert build_tables([cls]).keys() == {"table2"}


def test_bad_results_raise_clear_errors() -> None:
    with pytest.raises(ValueError, match="keys 'task' and 'name'"):
        build_table3([{"chamfer": 1.0}])
    with pytest.raises(ValueError, match="needs a 'modes' mapping"):
        build_table3([{"task": "reconstruction", "name": "x"}])
    with pytest.raises(ValueError, match="needs an 'accuracy' mapping"):
        build_table2([{"task": "classification", "name": "x"}])


def test_cli_collects_metrics_of_run_folders(tmp_path, capsys) -> None:
    import json

    from tvrecon.report.tables import collect_results, main

    for i, res in enumerate([FULL, VIS, TAC]):
        run = tmp_path / "sweep" / f"{i}_{res['name']}"
        run.mkdir(parents=True)
        (run / "metrics.json").write_text(json.dumps(res))
    assert [r["name"] for r in collect_results([tmp_path / "sweep"])] == ["full", "visual_only", "tactile_only"]
    assert main([str(tmp_path / "sweep"), "--out", str(tmp_path / "tables")]) == 0
    out = capsys.readouterr().out
    assert out.startswith(format_tables(build_tables([FULL, VIS, TAC])))
    assert "13.50" in out and "15.65" in out and "5.32" in out
    assert (tmp_path / "tables" / "table3.csv").is_file()


def test_cli_errors_name_the_problem(tmp_path, capsys) -> None:
    from tvrecon.report.tables import main

    with pytest.raises(SystemExit):
        main([str(tmp_path / "missing")])
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(tmp_path)])
    assert "no metrics.json" in capsys.readouterr().err
    (tmp_path / "metrics.json").write_text('{"task": "reconst')
    with pytest.raises(SystemExit):
        main([str(tmp_path)])
    assert "is not valid JSON" in capsys.readouterr().err


def test_touch_controls_table_only_for_models_tested_with_them() -> None:
    controlled = _recon(
        "full", "tactile_visual",
        {"visual": 11.94, "tv@2": 11.96, "tv@10": 12.16, "tv@10:other": 12.13, "tv@10:blank": 12.34},
        {"bottle": 4.5},
    )  # fmt: skip
    tables = build_tables([controlled, VIS])
    rows = _csv_rows(tables["touch_controls"].to_csv())
    assert rows[0] == [
        "Model", "Touches", "No touch", "Own touches", "Another object's touches", "Blank tactile images"
    ]  # fmt: skip
    assert rows[1:] == [["Ours", "10", "11.94", "12.16", "12.13", "12.34"]]  # visual_only has no controls
    # the controls never become a model's primary (Table 3/4) mode
    ours = [r for r in _csv_rows(tables["table4"].to_csv()) if r[0] == "Ours"]
    assert ours[0][-1] == "4.50" and "Ours: tv@10" in tables["table4"].to_markdown()
    assert "touch_controls" not in build_tables([FULL, VIS])
    assert format_tables(tables).index("Table 4") < format_tables(tables).index("Touch controls")


def test_touch_controls_get_a_row_at_every_touch_count_tested() -> None:
    modes = {"visual": 20.0, "tv@2": 9.0, "tv@2:other": 15.0, "tv@2:blank": 19.0, "tv@5": 7.0}
    modes |= {"tv@5:other": 16.0, "tv@5:blank": 20.5}
    rows = _csv_rows(build_tables([_recon("chart_based", "tactile_visual", modes)])["touch_controls"].to_csv())
    assert rows[1:] == [
        ["Chart-based (Smith et al. 2020)", "2", "20.00", "9.00", "15.00", "19.00"],
        ["Chart-based (Smith et al. 2020)", "5", "20.00", "7.00", "16.00", "20.50"],
    ]


def test_table3_assembles_the_chart_based_row_like_the_papers_and_borrows_a_missing_visual() -> None:
    chart = [
        _recon("chart_based", "tactile_visual", {"visual": 14.0 + s, "tv@2": 9.0 + s, "tv@10": 6.0 + s})
        for s in (0.0, 1.0)
    ]
    chart_tactile = _recon("chart_based_tactile", "tactile", {"tactile@10": 17.0})
    rows = _csv_rows(build_table3([*chart, chart_tactile]).to_csv())
    layout = next(r for r in rows if r[0] == "Chart-based (paper layout)")
    # no chart_based_visual run: the Visual column is chart_based's own, touches masked out (starred)
    assert layout[1:] == ["14.50*", "-", "-", "17.00", "9.50", "-", "6.50"]
    with_visual = [*chart, chart_tactile, _recon("chart_based_visual", "visual", {"visual": 13.0})]
    layout = next(r for r in _csv_rows(build_table3(with_visual).to_csv()) if r[0] == "Chart-based (paper layout)")
    assert layout[1] == "13.00"
    # a T&V model alone gets no assembled row: its own row already says everything
    assert not [r for r in _csv_rows(build_table3(chart).to_csv()) if "paper layout" in r[0]]


def test_refined_modes_get_their_own_table3_row() -> None:
    vis = _recon("visual_only", "visual", {"visual": 13.5, "visual+refine@2": 12.0, "visual+refine@5": 10.0}, {})
    full = _recon("full", "tactile_visual", {"visual": 14.0, "tv@2": 12.5, "tv@2+refine": 11.0}, {})
    table = build_table3([vis, full], touches=(2, 5))
    rows = {r[0]: r for r in _csv_rows(table.to_csv())[1:]}
    assert rows["Visual only (Pixel2Mesh) + touch refinement"][1:] == ["-", "-", "-", "12.00", "10.00"]
    assert rows["Ours + touch refinement"][1:] == ["-", "-", "-", "11.00", "-"]
    assert rows["Ours"][1:] == ["14.00*", "-", "-", "12.50", "-"]  # the refined modes stay out of the model's row
    assert any("touch refinement" in note for note in table.notes)


def test_fscore_table_rows_without_and_with_refinement() -> None:
    def with_f(result: dict, values: dict[str, tuple[float, float]]) -> dict:
        for mode, (f1, f2) in values.items():
            result["modes"][mode].update({"fscore@0.01": f1, "fscore@0.02": f2})
        return result

    vis = with_f(
        _recon("visual_only", "visual", {"visual": 13.5, "visual+refine@2": 12.0}, {}),
        {"visual": (0.40, 0.70), "visual+refine@2": (0.45, 0.75)},
    )
    tg = with_f(
        _recon("touch_geometry", "tactile_visual", {"visual": 14.0, "tv@2": 9.0, "tv@2+refine": 8.0}, {}),
        {"visual": (0.35, 0.65), "tv@2": (0.5, 0.8), "tv@2+refine": (0.55, 0.85)},
    )
    tables = build_tables([vis, tg])
    rows = _csv_rows(tables["fscore"].to_csv())
    assert rows[0] == ["Model", "Touches", "F@0.01", "F@0.02", "F@0.01 + touch refinement", "F@0.02 + touch refinement"]
    assert rows[1:] == [
        ["Visual only (Pixel2Mesh)", "0", "40.0", "70.0", "-", "-"],
        ["Visual only (Pixel2Mesh)", "2", "40.0", "70.0", "45.0", "75.0"],
        ["Touch geometry (beyond the paper)", "0", "35.0", "65.0", "-", "-"],
        ["Touch geometry (beyond the paper)", "2", "50.0", "80.0", "55.0", "85.0"],
    ]
    assert "fscore" not in build_tables([FULL])  # no F-scores in the results: no table


def test_table2_rows_and_captions_name_the_touches_and_the_split(tmp_path) -> None:
    """Runs of one model on two split protocols are two labelled rows, never averaged; the caption names the data; a
    run folder from before ``data_protocol`` was recorded gets it from its ``.hydra/config.yaml``."""
    import json

    from tvrecon.report.tables import collect_results

    sweep = {"touch": "PaperSweepTouchPolicy", "split": "shared_base"}
    results = [
        {"task": "classification", "name": "classify", "seed": 0, "accuracy": {"1": 0.6}, "data_protocol": sweep},
        {
            "task": "classification",
            "name": "classify",
            "seed": 0,
            "accuracy": {"1": 0.4},
            "data_protocol": {**sweep, "split": "unseen"},
        },
    ]
    table = build_table2(results)
    rows = _csv_rows(table.to_csv())
    assert [r[:2] for r in rows[1:]] == [
        ["Tactile classifier [the paper's touches (centre aim, side-to-top sweep), shared_base split]", "60.0 +- 0.0"],
        ["Tactile classifier [the paper's touches (centre aim, side-to-top sweep), unseen split]", "40.0 +- 0.0"],
    ]
    assert any(n.startswith("Data: the paper's touches") and "shared_base split; " in n for n in table.notes)
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / "metrics.json").write_text(json.dumps({k: v for k, v in results[0].items() if k != "data_protocol"}))
    (run / ".hydra" / "config.yaml").write_text("data:\n  touch: {cone_deg: 15.0}\n  library: {deform: 0.1}\n")
    (loaded,) = collect_results([run])
    assert loaded["data_protocol"] == {"touch": "ConeTouchPolicy", "split": "unseen"}
    assert "Data: cone touches (random surface points), unseen split." in build_table2([loaded]).notes


def test_seed_summary_puts_a_tactile_only_models_touches_under_its_touch_columns() -> None:
    from tvrecon.report.seed_summary import build_seed_summary

    tactile = [
        {**_recon("tactile_only", "tactile", {"tactile@2": 28.0 + s, "tactile@10": 22.0 + s}), "seed": 42 + s}
        for s in (0, 2)
    ]
    fusion = [{**_recon("full", "tactile_visual", {"visual": 12.0, "tv@10": 10.0 + s}), "seed": 42 + s} for s in (0, 2)]
    table = build_seed_summary([*tactile, fusion[0], fusion[1], VIS])  # VIS: one seed, no row
    rows = _csv_rows(table.to_csv())
    header = rows[0]
    assert header[3:6] == ["2 touches", "5 touches", "10 touches"]
    by_name = {r[0]: dict(zip(header, r)) for r in rows[1:]}
    assert set(by_name) == {"Tactile only", "Ours"}
    assert by_name["Tactile only"]["No touch"] == "-" and by_name["Tactile only"]["5 touches"] == "-"
    assert by_name["Tactile only"]["2 touches"] == "29.00 +- 1.41"
    assert by_name["Tactile only"]["10 touches"] == "23.00 +- 1.41"
    assert by_name["Ours"]["No touch"] == "12.00 +- 0.00" and by_name["Ours"]["10 touches"] == "11.00 +- 1.41"
    assert "blank view" in table.to_markdown()
