"""One bad run does not stop the tables or the evaluation of the others.

``tables`` skips a truncated ``metrics.json`` with a warning (as eval.py skips an unreadable checkpoint); eval.py
skips a run folder without ``.hydra/config.yaml``, and a corrupt best checkpoint falls back to ``last.ckpt``.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from pathlib import Path

import pytest
from conftest import compose_config
from test_faults import _fake_run
from test_tables import FULL, VIS

from tvrecon.report.tables import collect_results, main


def test_tables_skip_a_truncated_metrics_json_and_print_the_others(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    for name, result in [("0_full", FULL), ("1_visual_only", VIS)]:
        (tmp_path / name).mkdir()
        (tmp_path / name / "metrics.json").write_text(json.dumps(result))
    (tmp_path / "2_killed").mkdir()
    (tmp_path / "2_killed" / "metrics.json").write_text(json.dumps(FULL)[:40])  # a run killed while writing it
    with caplog.at_level(logging.WARNING, logger="tvrecon.report.tables"):
        assert [r["name"] for r in collect_results([tmp_path])] == ["full", "visual_only"]
    assert "skipping" in caplog.text and "2_killed" in caplog.text and "not valid JSON" in caplog.text
    assert main([str(tmp_path)]) == 0
    assert "13.50" in capsys.readouterr().out


def _eval_cfg(sweep: Path, out: Path):
    overrides = [f"run_dir={sweep}", "eval_touches=[2]", "export=false", "+trainer.limit_test_batches=1"]
    return compose_config("eval", overrides, out)


@pytest.mark.slow
def test_eval_sweep_skips_a_run_without_its_config_and_falls_back_to_last_ckpt(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from eval import evaluate

    sweep = tmp_path / "sweep"
    good = _fake_run(sweep / "0_smoke")
    no_config = _fake_run(sweep / "1_smoke")
    shutil.rmtree(sweep / "1_smoke" / ".hydra")
    last = _fake_run(sweep / "2_smoke")
    best = last.parent / "epoch=0-step=1.ckpt"  # the newest non-last file: eval.py's first pick
    best.write_bytes(last.read_bytes()[:1000])
    stamp = time.time() + 10
    os.utime(best, (stamp, stamp))
    with caplog.at_level(logging.WARNING, logger="eval"):
        out = evaluate(_eval_cfg(sweep, tmp_path / "eval"))
    assert [r["checkpoint"] for r in out["results"]] == [str(good), str(last)]
    assert out["skipped"] == [str(no_config)]
    assert f"{best}" in caplog.text and "evaluating that run's last.ckpt instead" in caplog.text
    assert "skipping" in caplog.text and ".hydra/config.yaml" in caplog.text
