"""Per-class accuracy table and confusion matrices of the classifiers (tvrecon.report.cls_report)."""

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from tvrecon.report.cls_report import (
    build_per_class_table,
    confusion_by_touches,
    file_stem,
    plot_accuracy_by_touches,
    plot_confusion,
    plot_per_class,
    write_classification_plots,
    write_confusion_plots,
)
from tvrecon.report.run_report import report_tables
from tvrecon.report.tables import build_tables

NAMES = ["cube", "gear", "mug"]


def result(seed: int, k: int, matrix: list[list[int]]) -> dict:
    m = np.asarray(matrix)
    per_class = {NAMES[c]: float(m[c, c] / m[c].sum()) for c in range(3) if m[c].sum() > 0}
    return {
        "task": "classification",
        "name": "classify",
        "seed": seed,
        "num_touches": k,
        "accuracy": {str(k): float(np.trace(m) / m.sum())},
        "confusion": {str(k): matrix},
        "per_class": {str(k): per_class},
        "classes": NAMES,
    }


RUNS = [
    result(0, 1, [[2, 1, 1], [0, 4, 0], [1, 1, 2]]),
    result(1, 1, [[4, 0, 0], [1, 3, 0], [0, 2, 2]]),
    result(0, 10, [[4, 0, 0], [0, 4, 0], [0, 0, 4]]),
]


def test_per_class_table_mean_std_over_seeds() -> None:
    table = build_per_class_table(RUNS)
    assert table.header == ["Class", "1-touch", "10-touch"]
    rows = {r[0]: r[1:] for r in table.rows}
    # cube with 1 touch: 2/4 and 4/4 -> mean 75.0, sample std 35.4
    assert rows["cube"] == ["75.0 +- 35.4", "100.0 +- 0.0"]
    assert rows["gear"] == ["87.5 +- 17.7", "100.0 +- 0.0"]
    assert rows["mug"] == ["50.0 +- 0.0", "100.0 +- 0.0"]


def test_confusion_is_summed_over_runs_per_touch_count() -> None:
    by_k = confusion_by_touches(RUNS)
    assert sorted(by_k) == [1, 10]
    counts, names, runs = by_k[1]
    np.testing.assert_array_equal(counts, [[6, 1, 1], [1, 7, 0], [1, 3, 4]])
    assert names == NAMES and runs == 2
    other = {**RUNS[1], "classes": ["a", "b", "c"]}
    with pytest.raises(ValueError, match="different classes"):
        confusion_by_touches([RUNS[0], other])
    old = {"task": "classification", "name": "classify", "seed": 0, "accuracy": {"1": 0.5}}  # before confusion
    assert confusion_by_touches([old]) == {} and build_per_class_table([old]).rows == []


def test_confusion_plots_are_written_for_fewest_and_most_touches(tmp_path: Path) -> None:
    paths = write_confusion_plots(RUNS, tmp_path)
    assert [p.name for p in paths] == ["confusion_1touch.png", "confusion_10touch.png"]
    image = mpimg.imread(paths[0])
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert not list(tmp_path.glob("*.tmp*"))
    with pytest.raises(ValueError, match="must be"):
        plot_confusion(np.ones((2, 3)), ["a", "b"], tmp_path / "bad.png", "bad")


def test_accuracy_curves_with_the_control_are_drawn(tmp_path: Path) -> None:
    runs = [{**r, "accuracy_other": {k: 0.0 for k in r["accuracy"]}} for r in RUNS]
    path = plot_accuracy_by_touches(runs, tmp_path / "acc.png")
    assert path is not None and mpimg.imread(path).shape[0] > 100
    recon = {"task": "reconstruction", "name": "full", "modes": {}}
    assert plot_accuracy_by_touches([recon], tmp_path / "none.png") is None and not (tmp_path / "none.png").exists()
    names = [p.name for p in write_classification_plots(RUNS, tmp_path / "all")]
    assert names == ["confusion_1touch.png", "confusion_10touch.png", "accuracy_by_touches.png"]


def test_models_are_kept_apart(tmp_path: Path) -> None:
    other = {**RUNS[2], "name": "classify_touch_set", "confusion": {"10": [[4, 0, 0], [0, 2, 2], [0, 0, 4]]}}
    other["per_class"] = {"10": {"cube": 1.0, "gear": 0.5, "mug": 1.0}}
    table = build_per_class_table([*RUNS, other])
    assert table.header[1:] == [
        "Tactile classifier 1-touch",
        "Tactile classifier 10-touch",
        "Touch-set classifier (beyond the paper) 10-touch",
    ]
    assert {r[0]: r[3] for r in table.rows}["gear"] == "50.0 +- 0.0"
    names = [p.name for p in write_confusion_plots([*RUNS, other], tmp_path)]
    assert names == [
        "confusion_classify_1touch.png",
        "confusion_classify_10touch.png",
        "confusion_classify_touch_set_10touch.png",
    ]
    # which classes each model loses: gear (50% for the touch set) is drawn, cube (100% for both) is not
    bars = plot_per_class([*RUNS, other], tmp_path / "bars.png")
    assert bars is not None and mpimg.imread(bars).shape[1] > 100
    assert plot_per_class(RUNS, tmp_path / "one.png") is None and not (tmp_path / "one.png").exists()
    assert plot_per_class([*RUNS, other], tmp_path / "k1.png", touches=1) is None  # the touch set has no 1-touch run
    names = [p.name for p in write_classification_plots([*RUNS, other], tmp_path / "all")]
    assert names[-2:] == ["accuracy_by_touches.png", "per_class_by_model.png"]
    fused = "Late fusion (mean_log_prob, beyond the paper): Tactile classifier + Contact-cloud classifier"
    assert file_stem(fused) == "Late_fusion_mean_log_prob_beyond_the_paper_Tactile_classifier_Contact-cloud_classifier"
    assert file_stem("classify_contact_cloud@8headings") == "classify_contact_cloud_8headings"


def test_tables_and_report_include_the_per_class_table(tmp_path: Path) -> None:
    assert set(build_tables(RUNS)) == {"table2", "table2_per_class"}
    text = report_tables(RUNS, tmp_path, echo=False)
    assert "Table 2 per class" in text and text.index("Table 2:") < text.index("Table 2 per class")
    assert (tmp_path / "tables" / "confusion_10touch.png").is_file()
    assert (tmp_path / "tables" / "table2_per_class.csv").read_text().startswith("Class,1-touch,10-touch")


def test_runs_asked_over_several_headings_are_their_own_row(tmp_path: Path) -> None:
    from tvrecon.report.cls_report import build_table2, model_key, model_label

    plain = result(0, 10, [[4, 0, 0], [0, 4, 0], [0, 0, 4]])
    turned = {**result(0, 10, [[2, 2, 0], [0, 4, 0], [0, 0, 4]]), "headings": 8}
    assert model_key(plain) == "classify" and model_key({**plain, "headings": 1}) == "classify"
    assert model_key(turned) == "classify@8headings"
    assert model_label("classify@8headings").endswith(", 8 headings averaged")
    rows = {r[0]: r for r in build_table2([plain, turned]).rows}
    assert len(rows) == 2  # the same checkpoint asked two ways is never averaged as two seeds
    [label] = [k for k in rows if k.endswith("8 headings averaged")]
    assert rows[label][-1] == "83.3 +- 0.0" and "100.0 +- 0.0" in [r[-1] for r in rows.values()]
    paths = write_confusion_plots([plain, turned], tmp_path)
    assert all("@" not in p.name for p in paths) and len(paths) == 2
