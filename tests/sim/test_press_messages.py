"""Issue 28: a press that does not fit in the domain names every term and the fix (before: "the domain (16 cells) is
too small for a pad of thickness 2.5 cells" for ``--depth 1e6`` or ``--n-grid 16``, blaming the pad)."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from tvrecon.sim.__main__ import main
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig

SPHERE = trimesh.creation.icosphere(subdivisions=2, radius=0.5)


def test_too_deep_a_press_names_the_depth_and_n_grid() -> None:
    sim = EIPSimulator(SensorConfig(resolution=(8, 8), layers=3), PressConfig(n_grid=32, depth=1e6))
    with pytest.raises(ValueError, match=r"max_depth 1e\+06 \(the hand's travel; a depth of 1e\+06 cells sets it"):
        sim.press(SPHERE, None, [0.0, 0.0, -1.0])


def test_smallest_n_grid_is_one_line_naming_the_sum(tmp_path: Path, capsys) -> None:
    args = ["press", "--shape", "sphere", "--n-grid", "16", "--resolution", "8", "--layers", "3"]
    assert main([*args, "--out", str(tmp_path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("python -m tvrecon.sim: error: the press does not fit in the domain")
    assert "= 10 cells, more than half the domain (n_grid / 2 = 8 cells)" in lines[0] and "raise n_grid" in lines[0]
