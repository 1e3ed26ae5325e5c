"""sweep_figure ends bad input in one line (no traceback) and writes under outputs/ without --out."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROG = "python -m tvrecon.data.touches.sweep_figure"
SMALL = ["--preset", "cls_tiny", "sensor.resolution=[6,6]", "sensor.layers=3", "press.n_grid=32"]


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "tvrecon.data.touches.sweep_figure", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sweep", "--shape", "bogus", *SMALL], "--shape 'bogus' is not a class of preset 'cls_tiny'; its classes: "),
        (["sheet", "--elevation", "200", *SMALL], "--elevation must be in [-90, 90] degrees"),
    ],
)
def test_bad_input_is_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    done = _run(args, tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip() == done.stderr.strip().splitlines()[0]
    assert done.stderr.startswith(f"{PROG}: error: {message}")
    assert list(tmp_path.iterdir()) == []


def test_without_out_the_figure_goes_under_outputs(tmp_path: Path) -> None:
    done = _run(["sweep", "--shape", "gear", "--touches", "2", *SMALL], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    [png] = list((tmp_path / "outputs" / "sweep_figure").glob("*/sweep.png"))
    assert done.stdout.strip().splitlines()[-1] == f"outputs in {png.parent.resolve()}"
    assert [p.name for p in tmp_path.iterdir()] == ["outputs"]  # nothing in the current folder itself
