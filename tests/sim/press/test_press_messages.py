"""A press that does not fit in the domain names every term and the fix (before: "the domain (16 cells) is
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


def test_a_mesh_in_mm_says_how_it_was_rescaled_and_a_second_press_into_one_out_warns(tmp_path: Path, capsys) -> None:
    """A --position in the file's own units was refused without a word about the rescaling, and two
    presses into one --out mixed their files silently."""
    part = trimesh.creation.box(extents=(50.0, 50.0, 50.0))
    part.apply_translation((100.0, 0.0, 25.0))  # a 50 mm cube off the origin, as a CAD export
    path = tmp_path / "cube_mm.stl"
    part.export(path)
    args = ["press", "--shape", str(path), "--depth", "0.5", "--resolution", "8", "--layers", "3", "--n-grid", "32"]
    args += ["--frames", "1", "--ply", "0", "--threads", "1", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    out = capsys.readouterr()
    assert "cube_mm.stl: centred at [100.0, 0.0, 25.0] and scaled by 1/50 to a largest extent of 1" in out.out
    assert "--position is in these units" in out.out and "warning" not in out.err
    assert main(args) == 0
    assert "held an earlier press: its files are replaced" in capsys.readouterr().out


def test_an_object_many_domains_across_warns_about_its_units() -> None:
    """A 50 mm cube given in mm (50 units) was pressed silently as one flat face."""
    cube_mm = trimesh.creation.box(extents=(50.0, 50.0, 50.0))
    sim = EIPSimulator(SensorConfig(resolution=(8, 8), layers=3), PressConfig(n_grid=32, depth=0.5))
    with pytest.warns(RuntimeWarning, match=r"the object is 50 domains across .*mesh.apply_scale\(1e-3\)"):
        sim.press(cube_mm, None, [0.0, 0.0, -1.0])
