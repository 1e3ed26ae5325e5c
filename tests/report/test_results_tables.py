"""The docs' results blocks equal what ``python -m tvrecon.report.results_tables`` renders from ``results/``, every
results run has a complete manifest, and the renderer on a tiny synthetic results folder."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tvrecon.report.results_tables import (
    MANIFEST_FIELDS,
    RENDERERS,
    fill_blocks,
    find_blocks,
    load_runs,
    main,
    render,
)

REPO = Path(__file__).resolve().parents[2]
RESULTS = REPO / "results"


def _docs() -> list[Path]:
    return [p for p in [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))] if p.is_file()]


def test_the_docs_blocks_equal_the_render(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["--check", "--root", str(RESULTS)])
    out = capsys.readouterr().out
    assert code == 0, f"results blocks differ from results/ (run python -m tvrecon.report.results_tables):\n{out}"


def test_every_table_page_holds_its_block() -> None:
    names = {name for page in _docs() for name, _ in find_blocks(page.read_text())}
    assert {"table1", "table2", "table3", "table4", "benchmarks", "headline"} <= names
    for n in ("1", "2", "3", "4"):
        page = REPO / "docs" / "reproduce" / f"table{n}.md"
        assert f"table{n}" in {name for name, _ in find_blocks(page.read_text())}, page


def _manifest_of(metrics: Path) -> Path:
    folder = metrics.parent
    while not (folder / "manifest.json").is_file():
        assert folder != RESULTS, f"{metrics} has no manifest.json beside or above it"
        folder = folder.parent
    return folder / "manifest.json"


def test_every_results_run_has_a_complete_manifest() -> None:
    metrics = sorted(RESULTS.rglob("metrics.json"))
    assert len(metrics) >= 30  # the tables' runs
    git = shutil.which("git") is not None and (REPO / ".git").exists()
    commits = set()
    for path in metrics:
        json.loads(path.read_text())  # valid JSON
        manifest = json.loads(_manifest_of(path).read_text())
        missing = [f for f in MANIFEST_FIELDS if f not in manifest]
        assert not missing, f"{_manifest_of(path)} lacks {missing}"
        assert isinstance(manifest["command"], str) and manifest["command"].strip(), path
        assert re.fullmatch(r"\d{4}-\d{2}-\d{2}", str(manifest["date"])), path
        assert manifest["wall_s"] is None or float(manifest["wall_s"]) > 0, path
        assert manifest["commit"] is None or re.fullmatch(r"[0-9a-f]{7,40}", manifest["commit"]), path
        if manifest["commit"]:
            commits.add(manifest["commit"])
    if git:
        for commit in sorted(commits):
            found = subprocess.run(
                ["git", "-C", str(REPO), "cat-file", "-e", f"{commit}^{{commit}}"], capture_output=True
            )
            assert found.returncode == 0 or (REPO / ".git" / "shallow").exists(), f"commit {commit} is not in git"


# ---- the renderer on a tiny synthetic results folder ----


def _recon(name: str, seed: int, visual: float, touched: dict[int, float] | None = None) -> dict:
    per_class = {"bottle": visual - 1.0, "cube": visual + 1.0}
    modes = {"visual": {"chamfer": visual, "per_class": per_class}}
    for k, v in (touched or {}).items():
        modes[f"tv@{k}"] = {"chamfer": v, "per_class": {"bottle": v - 1.0, "cube": v + 1.0}}
    modality = "tactile_visual" if touched else "visual"
    return {"task": "reconstruction", "name": name, "modality": modality, "seed": seed, "modes": modes}


def _write_run(folder: Path, metrics: dict, command: str, preset: str = "tiny") -> None:
    folder.mkdir(parents=True)
    (folder / "metrics.json").write_text(json.dumps(metrics))
    manifest = {f: None for f in MANIFEST_FIELDS}
    manifest.update(command=command, data_preset=preset, seed=metrics.get("seed"), date="2026-01-01")
    (folder / "manifest.json").write_text(json.dumps(manifest))


@pytest.fixture
def tiny_results(tmp_path: Path) -> Path:
    root = tmp_path / "results"
    cmd = "python train.py experiment={} data=tiny trainer.max_epochs=3 seed={}"
    _write_run(root / "table3" / "visual_only_s1", _recon("visual_only", 1, 10.0), cmd.format("visual_only", 1))
    _write_run(root / "table3" / "visual_only_s2", _recon("visual_only", 2, 12.0), cmd.format("visual_only", 2))
    full = {2: 9.0, 5: 8.0, 10: 5.5}
    _write_run(root / "table3" / "full_s1", _recon("full", 1, 11.0, full), cmd.format("full", 1))
    cls = {"task": "classification", "name": "classify_paper_cpu", "seed": 0, "accuracy": {"10": 0.9}}
    _write_run(root / "table2" / "paper_s0", cls, "python train.py experiment=classify_paper_cpu seed=0", "cls_tiny")
    return root


def test_table3_rows_are_seed_means_beside_the_paper_with_ratio_and_command(tiny_results: Path) -> None:
    text = render("table3", tiny_results)
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| Model")}  # fmt: skip
    assert rows["Paper: Ours (the paper's fusion model)"][-1] == "0.38x"  # 5.32 / 14.07
    assert rows["Visual only (Pixel2Mesh)"][:2] == ["1, 2", "11.00 +- 1.41"]
    full = rows["The paper's fusion model (`full`)"]
    assert full[:2] == ["1", "11.00*"] and full[-2:] == ["5.50", "0.50x"]  # 5.5 / mean(10, 12)
    assert "seed=<seed>" in text and "`python train.py experiment=full data=tiny trainer.max_epochs=3 seed=1`" in text


def test_table3_keeps_runs_of_another_precision_apart_with_their_own_reference(tiny_results: Path) -> None:
    cmd = "python train.py experiment={} data=tiny trainer.max_epochs=3 seed={} trainer.precision=bf16-mixed"
    _write_run(tiny_results / "table3" / "visual_only_bf16_s1", _recon("visual_only", 1, 20.0), cmd.format("v", 1))
    _write_run(tiny_results / "table3" / "full_bf16_s1", _recon("full", 1, 30.0, {10: 10.0}), cmd.format("full", 1))
    text = render("table3", tiny_results)
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| Model")}  # fmt: skip
    assert rows["Visual only (Pixel2Mesh)"][:2] == ["1, 2", "11.00 +- 1.41"]  # the 32-bit runs alone
    assert rows["Visual only (Pixel2Mesh), bf16-mixed"][:2] == ["1", "20.00"]
    assert rows["The paper's fusion model (`full`), bf16-mixed"][-1] == "0.50x"  # 10 / 20: its own precision's


def test_table4_and_table2_render_ours_and_the_papers(tiny_results: Path) -> None:
    t4 = render("table4", tiny_results)
    assert "| Paper: the paper's fusion model" in t4 and "5.32" in t4
    row = next(line for line in t4.splitlines() if line.startswith("| The paper's fusion model"))
    cells = [c.strip() for c in row.split("|")[2:-1]]
    assert cells == ["1", "4.50", "-", "-", "-", "6.50", "-", "-", "-", "-", "-", "5.50"]  # bottle, cube, average
    t2 = render("table2", tiny_results)
    assert "Table 2 on `cls_tiny`" in t2 and "92.9 +- 0.3" in t2 and "90.0 +- 0.0" in t2


def test_fill_and_check_name_a_stale_block(tiny_results: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tiny_results.parent / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text("# Page\n\n<!-- results:table4 -->\nhand-edited\n<!-- /results:table4 -->\n\nafter\n")
    assert main(["--check", "--root", str(tiny_results), str(page)]) == 1
    assert f"{page}: results:table4" in capsys.readouterr().out
    assert "hand-edited" in page.read_text()  # --check writes nothing
    assert main(["--root", str(tiny_results), str(page)]) == 0
    text = page.read_text()
    assert text.endswith("<!-- /results:table4 -->\n\nafter\n") and "Table 4" in text
    assert main(["--check", "--root", str(tiny_results), str(page)]) == 0
    # a results file that changes makes the block stale again
    (tiny_results / "table3" / "full_s1" / "metrics.json").write_text(
        json.dumps(_recon("full", 1, 11.0, {2: 9.0, 5: 8.0, 10: 4.0}))
    )
    assert main(["--check", "--root", str(tiny_results), str(page)]) == 1


def test_headline_links_follow_the_page(tiny_results: Path) -> None:
    (tiny_results / "table1").mkdir()
    text = "<!-- results:headline -->\n<!-- /results:headline -->\n"
    readme = fill_blocks(text, tiny_results, tiny_results.parent / "README.md")
    docs = fill_blocks(text, tiny_results, tiny_results.parent / "docs" / "index.md")
    nested = fill_blocks(text, tiny_results, tiny_results.parent / "docs" / "reproduce" / "index.md")
    assert "(docs/reproduce/table3.md)" in readme and "(reproduce/table3.md)" in docs and "(table3.md)" in nested
    assert "0.38x" in readme and "0.50x" in readme  # the paper's ratio and ours


def test_headline_and_table3_name_the_chart_based_row_beside_the_papers(tiny_results: Path) -> None:
    (tiny_results / "table1").mkdir()
    cmd = "python train.py experiment=chart_based data=tiny trainer.max_epochs=3 seed={}"
    for seed, tv in ((1, 6.0), (2, 8.0)):
        chart = _recon("chart_based", seed, 14.0, {2: 9.0, 5: 8.0, 10: tv})
        _write_run(tiny_results / "table3" / f"chart_based_s{seed}", chart, cmd.format(seed))
    headline = render("headline", tiny_results)
    assert "Chart-based 5.83 (0.43x)" in headline  # the paper's row
    # 7 / mean(10, 12) against Pixel2Mesh, 7 / 14 against its own answer with its touches masked out
    assert "Chart-based 7.00 +- 1.41 (0.64x Pixel2Mesh, 0.50x its own no-touch answer, 2 seeds)" in headline
    row3 = next(line for line in headline.splitlines() if line.startswith("| 3:"))
    assert row3.split(" | ")[1].endswith("Chart-based 5.83 (0.43x)") and len(row3.split(" | ")) == 4
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]] for line in
            render("table3", tiny_results).splitlines() if line.startswith("| ")}  # fmt: skip
    assert rows["On our data: Chart-based (Smith et al. 2020)"][1] == "14.00 +- 0.00*"
    assert rows["On our data: Chart-based (Smith et al. 2020)"][-1] == "0.50x +- 0.10"


def test_controls_block_gives_every_touch_count_its_seed_means(tiny_results: Path) -> None:
    cmd = "python train.py experiment=chart_based data=tiny trainer.max_epochs=3 seed={}"
    for seed, other in ((1, 12.0), (2, 14.0)):
        chart = _recon("chart_based", seed, 14.0, {5: 8.0, 10: 6.0})
        for k in (5, 10):
            chart["modes"] |= {f"tv@{k}:other": {"chamfer": other + k}, f"tv@{k}:blank": {"chamfer": 14.0}}
        _write_run(tiny_results / "table3" / f"chart_based_s{seed}", chart, cmd.format(seed))
    rows = [line.split("|")[1:-1] for line in render("table3_controls", tiny_results).splitlines()[4:6]]
    assert [[c.strip() for c in r] for r in rows] == [
        [
            "Chart-based (Smith et al. 2020)",
            "1, 2",
            "5",
            "14.00 +- 0.00",
            "8.00 +- 0.00",
            "18.00 +- 1.41",
            "14.00 +- 0.00",
        ],
        [
            "Chart-based (Smith et al. 2020)",
            "1, 2",
            "10",
            "14.00 +- 0.00",
            "6.00 +- 0.00",
            "23.00 +- 1.41",
            "14.00 +- 0.00",
        ],
    ]  # the full run of the fixture has no controls: no row


def test_unknown_block_and_missing_manifest_are_clear_errors(tiny_results: Path) -> None:
    with pytest.raises(ValueError, match="unknown results block 'table9'.*headline"):
        render("table9", tiny_results)
    (tiny_results / "table3" / "full_s1" / "manifest.json").unlink()
    with pytest.raises(FileNotFoundError, match="full_s1/metrics.json has no manifest.json"):
        load_runs(tiny_results / "table3")
    assert set(RENDERERS) >= {"headline", "table1", "table2", "table3", "table4", "benchmarks"}


def test_benchmark_rows_name_each_suites_figure(tiny_results: Path) -> None:
    ab = {"old_over_new_median": 1.5, "old_over_new_total": 1.4, "old_cpu_s_per_touch": 0.3,
          "new_cpu_s_per_touch": 0.2, "jobs_not_bit_identical": 0, "jobs": 4}  # fmt: skip
    _write_run(tiny_results / "bench" / "press_ab" / "a", ab, "python -m benchmarks.probes.bench_press_ab --old abc")
    runs = {"bench_sim": {"wall_s": 12.4, "returncode": 0}, "bench_press": {"wall_s": 3.0, "returncode": 1}}
    _write_run(tiny_results / "bench" / "suite" / "k", {"runs": runs}, "python -m benchmarks.run")
    text = render("benchmarks", tiny_results)
    assert "1.50x the old code (median; 0.3 -> 0.2 CPU-s a touch), 4 of 4 jobs bit-identical" in text
    assert "bench_sim 12 s; bench_press 3 s (exit 1)" in text and "`python -m benchmarks.run`" in text


def test_a_longer_schedule_is_a_row_apart_and_the_headline_keeps_the_schedule_of_the_papers_model(
    tiny_results: Path,
) -> None:
    (tiny_results / "table1").mkdir()
    long_cmd = "python train.py experiment={} data=tiny trainer.max_epochs=9 seed={}"
    short_cmd = "python train.py experiment={} data=tiny trainer.max_epochs=3 seed={}"
    # sorted after the 3-epoch runs, so a table that keeps the last group of a name would take it
    _write_run(tiny_results / "table3" / "visual_only_s3_e9", _recon("visual_only", 3, 8.0), long_cmd.format("v", 3))
    for seed, epochs, tv in ((1, 3, 5.0), (2, 3, 5.0), (1, 9, 4.0)):
        folder = tiny_results / "table3" / f"touch_geometry_s{seed}_e{epochs}"
        cmd = (long_cmd if epochs == 9 else short_cmd).format("touch_geometry", seed)
        _write_run(folder, _recon("touch_geometry", seed, 14.0, {2: 7.0, 5: 6.0, 10: tv}), cmd)
        manifest = json.loads((folder / "manifest.json").read_text())
        (folder / "manifest.json").write_text(json.dumps(manifest | {"wall_s": 1800.0 * epochs / 3}))

    row3 = next(line for line in render("headline", tiny_results).splitlines() if line.startswith("| 3:"))
    assert "Pixel2Mesh 11.00 +- 1.41 (2 seeds)" in row3  # the 3-epoch Pixel2Mesh, as the paper's model's runs
    assert "touch geometry 5.00 +- 0.00 (0.45x)" in row3 and "3 epochs" in row3

    seeds = {line.split("|")[1].strip(): line.split("|")[3].strip()
             for line in render("table3_touches", tiny_results).splitlines() if line.startswith("| ")}  # fmt: skip
    assert seeds["Visual only (Pixel2Mesh)"] == "11.00 +- 1.41"  # the one 9-epoch seed is not mixed in

    table = render("table3_schedules", tiny_results)
    rows = [[c.strip() for c in line.split("|")[1:-1]] for line in table.splitlines() if line.startswith("| ")]
    assert rows[1:] == [
        ["Visual only (Pixel2Mesh)", "3", "1, 2", "11.00 +- 1.41", "-", "-", "-"],
        ["Visual only (Pixel2Mesh)", "9", "3", "8.00", "-", "-", "-"],
        ["Touch geometry (beyond the paper)", "3", "1, 2", "14.00 +- 0.00", "5.00 +- 0.00", "0.45x", "30 +- 0"],
        ["Touch geometry (beyond the paper)", "9", "1", "14.00", "4.00", "0.50x", "90"],
    ]
    assert "full" not in table and "The paper's" not in table  # one schedule only: no row
