"""``python -m tvrecon.report.record_run``: a finished run folder -> results/<suite>/<run> with its manifest."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tvrecon.report.record_run import main
from tvrecon.report.results_tables import MANIFEST_FIELDS, load_runs


def _run_dir(root: Path, finished: bool = True) -> Path:
    run = root / "runs" / "full_s43"
    (run / ".hydra").mkdir(parents=True)
    overrides = ["experiment=full", "data=paper_cpu", "trainer.max_epochs=8", "seed=43", "paths.data_dir=/x/data"]
    overrides += ["hydra.run.dir=/x/runs/full_s43", "ckpt_path=/x/runs/full_s43/checkpoints/last.ckpt", "freeze=[a,b]"]
    (run / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    (run / ".hydra" / "hydra.yaml").write_text(
        f"hydra:\n  runtime:\n    cwd: {root}\n    choices:\n      data: paper_cpu\n"
    )
    (run / ".hydra" / "config.yaml").write_text("seed: 43\ntrainer:\n  accelerator: cpu\n  precision: 32-true\n")
    (run / "train.log").write_text(
        "[2026-12-07 19:30:00,001][train][INFO] - Starting training\n"
        "[2026-12-07 21:10:30,500][train][INFO] - Wrote metrics.json\n"
    )
    if finished:
        (run / "metrics.json").write_text(json.dumps({"task": "reconstruction", "name": "full", "modes": {}}))
        (run / "loss_curves.png").write_bytes(b"\x89PNG")
    return run


def test_a_finished_run_is_recorded_with_the_manifest_the_tables_read(tmp_path: Path) -> None:
    run = _run_dir(tmp_path)
    out = tmp_path / "results" / "table3" / "full_s43"
    assert main([str(run), str(out), "--machine", "AMD EPYC x2, AVX2", "--note", "side by side"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["loss_curves.png", "manifest.json", "metrics.json"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert set(MANIFEST_FIELDS) <= set(manifest)
    # the overrides that only place files are dropped; the rest is quoted for a shell
    assert (
        manifest["command"]
        == "python train.py experiment=full data=paper_cpu trainer.max_epochs=8 seed=43 'freeze=[a,b]'"
    )
    assert (manifest["data_preset"], manifest["seed"], manifest["wall_s"]) == ("paper_cpu", 43, 6030)
    assert (manifest["machine"], manifest["precision"], manifest["note"]) == (
        "AMD EPYC x2, AVX2",
        "32-true",
        "side by side",
    )
    (loaded,) = load_runs(tmp_path / "results" / "table3")
    assert loaded.result()["epochs"] == 8 and loaded.result()["fixed_visual"]


@pytest.mark.parametrize("case", ["unfinished", "not_a_run", "exists"])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(
    tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]
) -> None:
    run = _run_dir(tmp_path, finished=case != "unfinished")
    if case == "not_a_run":
        (run / ".hydra" / "overrides.yaml").unlink()
    out = tmp_path / "results" / "full_s43"
    if case == "exists":
        out.mkdir(parents=True)
        (out / "keep.txt").write_text("mine")
    assert main([str(run), str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    assert {"unfinished": "has not finished", "not_a_run": "not a train.py run", "exists": "--force"}[case] in err
    leftovers = sorted(p.name for p in out.parent.iterdir()) if out.parent.exists() else []
    assert leftovers == (["full_s43"] if case == "exists" else [])
    if case == "exists":
        assert [p.name for p in out.iterdir()] == ["keep.txt"]
        assert main([str(run), str(out), "--force", "--wall-s", "5"]) == 0
        assert json.loads((out / "manifest.json").read_text())["wall_s"] == 5 and not (out / "keep.txt").exists()
