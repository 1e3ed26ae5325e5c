"""Stale temporary files of killed runs are removed at the start of a job, and the first
on-the-fly simulation says how many touches it is about to simulate and where they are cached."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

from tvrecon.data.cache.housekeeping import job_start_time, remove_stale_tmp, uncached_items
from tvrecon.data.datamodule import ReconstructionDataModule


def _file(path: Path, age_s: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"partial")
    stamp = time.time() - age_s
    os.utime(path, (stamp, stamp))
    return path


def test_only_tmp_files_older_than_the_job_and_the_grace_period_go(tmp_path: Path) -> None:
    stale = [_file(tmp_path / "ab" / ".abcdef012345-x1.tmp", 7200), _file(tmp_path / ".write-probe-1.tmp", 7200)]
    writing = _file(tmp_path / "cd" / ".cdef01234567-x2.tmp", 5)  # another job's write in progress
    entry = _file(tmp_path / "ab" / "abcdef.npz", 7200)
    assert remove_stale_tmp(tmp_path, started=time.time()) == 2
    assert not any(p.exists() for p in stale) and writing.exists() and entry.exists()
    assert remove_stale_tmp(tmp_path / "missing") == 0 and remove_stale_tmp(None) == 0
    assert time.time() - 3600 * 24 * 365 < job_start_time() <= time.time()


def test_datamodule_setup_cleans_the_cache_and_announces_the_on_the_fly_touches(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    stale = _file(tmp_path / "ab" / ".abcdef012345-x1.tmp", 7200)
    dm = ReconstructionDataModule(train={"num_samples": 3}, cache_dir=tmp_path, min_touches=2, max_touches=2)
    with caplog.at_level(logging.INFO, logger="tvrecon.data.cache.housekeeping"):
        dm.setup("fit")
    assert not stale.exists()
    assert "removed 1 stale temporary file(s)" in caplog.text
    assert "split 'train': 3 of 3 items are not cached yet" in caplog.text and "(6 touches)" in caplog.text
    assert str(tmp_path.resolve()) in caplog.text and "tvrecon.data.generate" in caplog.text
    assert uncached_items(dm.datasets["train"], limit=2) == (3, False)  # sampled estimate for large splits


def test_generate_removes_stale_tmp_files_at_start(tmp_path: Path) -> None:
    from test_generate import ARGS

    from tvrecon.data.generate import main

    stale = _file(tmp_path / "ab" / ".abcdef012345-x1.tmp", 7200)
    main([*ARGS, f"cache_dir={tmp_path}", "workers=1", "splits=val"])
    assert not stale.exists()
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.suffix != ".npz"]
