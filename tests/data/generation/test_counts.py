"""Counts and workers are whole numbers in range (``num_samples=2.5`` was silently 2,
``workers=0`` silently meant all cores), and ``generate`` says so in one line naming the key."""

from __future__ import annotations

import pytest

from tvrecon.data.datamodule import ReconstructionDataModule
from tvrecon.data.generate import main
from tvrecon.utils.cli_errors import call_cli

PROG = "python -m tvrecon.data.generate"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"train": {"num_samples": 2.5}}, "data.train.num_samples must be a whole number, got 2.5"),
        ({"train": {"num_samples": 0}}, "data.train.num_samples must be >= 1, got 0"),
        ({"train": {"num_samples": 3}, "batch_size": 2.5}, "data.batch_size must be a whole number"),
        ({"train": {"num_samples": 3}, "pregenerate_workers": 0}, "data.pregenerate_workers must be >= 1"),
    ],
)
def test_datamodule_counts_are_whole_numbers_in_range(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        ReconstructionDataModule(**kwargs)


def test_generate_fractional_num_samples_is_one_line_naming_the_key(tmp_path, capsys) -> None:
    argv = ["preset=tiny", "train.num_samples=2.5", f"cache_dir={tmp_path}"]
    assert call_cli(main, argv, prog=PROG) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0] == f"{PROG}: error: data.train.num_samples must be a whole number, got 2.5"
    assert not any(tmp_path.iterdir())
