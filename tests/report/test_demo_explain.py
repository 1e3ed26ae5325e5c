"""The lines ``make demo`` prints after its tables, computed from a synthetic run's numbers (no training)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tvrecon.report.demo_explain import explain_touches
from tvrecon.report.results_tables import MANIFEST_FIELDS

SMOKE = {
    "task": "reconstruction",
    "name": "smoke",
    "modality": "tactile_visual",
    "modes": {
        "visual": {"chamfer": 43.23},
        "tv@2": {"chamfer": 43.60},
        "tv@5": {"chamfer": 44.14},
        "tv@10": {"chamfer": 45.02},
        "tv@2+refine": {"chamfer": 30.56},
        "tv@5+refine": {"chamfer": 26.63},
        "tv@10+refine": {"chamfer": 25.38},
        "tv@10:other": {"chamfer": 45.10},
        "tv@10:blank": {"chamfer": 44.90},
    },
}


def test_the_runs_own_numbers_say_which_rows_read_the_touches() -> None:
    text = explain_touches(SMOKE, results_root=None)
    assert "No touch 43.23; 2 / 5 / 10 touches 43.60 / 44.14 / 45.02" in text
    assert "the touches do not help (10 touches +4.1% against none)" in text
    assert "Another object's 10 touches: 45.10 against its own 45.02 (+0.2%)" in text
    assert "does not tell its own touches from another object's (within 5%)" in text
    assert "30.56 / 26.63 / 25.38 with 2 / 5 / 10 touches, 0.59x the no-touch answer with 10" in text
    assert "Table 1" not in text  # no results folder given


def test_a_model_that_reads_its_touches_is_told_so() -> None:
    result = json.loads(json.dumps(SMOKE))
    result["modes"]["tv@10"]["chamfer"] = 30.0
    result["modes"]["tv@10:other"]["chamfer"] = 40.0
    text = explain_touches(result, results_root=None)
    assert "the touches help (10 touches -30.6% against none)" in text
    assert (
        "40.00 against its own 30.00 (+33.3%): the answer depends on which object was touched (over 5% apart)" in text
    )


def _run(folder: Path, metrics: dict, command: str, wall_s: float | None) -> None:
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps(metrics))
    manifest = dict.fromkeys(MANIFEST_FIELDS)
    manifest.update(command=command, data_preset="paper_cpu", seed=metrics["seed"], wall_s=wall_s, machine="CPU")
    (folder / "manifest.json").write_text(json.dumps(manifest))


def test_the_paper_size_figure_and_command_come_from_the_results_folder(tmp_path: Path) -> None:
    root = tmp_path / "results"
    for seed, own, other in ((42, 10.0, 12.0), (43, 9.0, 9.9)):
        modes = {"visual": {"chamfer": 11.0}, "tv@10": {"chamfer": own}, "tv@10:other": {"chamfer": other}}
        metrics = {"task": "reconstruction", "name": "full", "seed": seed, "modes": modes}
        _run(root / "table3" / f"full_s{seed}", metrics, f"python train.py experiment=full seed={seed}", 3600.0)
    vis = {"task": "reconstruction", "name": "visual_only", "seed": 42, "modes": {"visual": {"chamfer": 12.0}}}
    _run(root / "table3" / "visual_only_s42", vis, "python train.py experiment=visual_only seed=42", None)
    text = explain_touches(SMOKE, results_root=root)
    assert "on `paper_cpu` (650 training objects of 35 classes) another object's 10 touches" in text  # its config
    assert "another object's 10 touches score 15.0% worse than its own (mean of 2 seeds)" in text  # (20 + 10) / 2
    assert "10 touches give 0.79x Pixel2Mesh's error (1 seed; the paper: 0.38x)" in text  # 9.5 / 12
    assert "`python -m tvrecon.data.generate preset=paper_cpu workers=2`" in text
    assert "`python train.py experiment=full seed=42` (about 1.0 h a seed there; machine: CPU)" in text
    assert "docs/reproduce/table3.md" in text


def test_a_classification_result_is_refused() -> None:
    with pytest.raises(ValueError, match="needs a reconstruction result"):
        explain_touches({"task": "classification", "name": "classify", "accuracy": {}}, results_root=None)


def test_the_training_split_is_read_inside_a_hydra_app() -> None:
    from hydra import compose, initialize_config_dir

    from tvrecon.report.demo_explain import _training_split

    configs = Path(__file__).resolve().parents[2] / "configs"
    with initialize_config_dir(config_dir=str(configs), version_base="1.3"):  # as in train.py's run
        compose(config_name="train")
        assert _training_split("paper_cpu") == " (650 training objects of 35 classes)"
    assert _training_split("no_such_preset") == ""
