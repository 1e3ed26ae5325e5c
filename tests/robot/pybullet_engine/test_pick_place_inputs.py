"""The robot CLI's bad object inputs end in one line naming the file, exit 2 (before: a NaN vertex ran
to the end and exited 0, random bytes said "No module named 'charset_normalizer'", ``object=mug.obj`` for a missing
file said "unknown shape class").
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

pytest.importorskip("pybullet")

PROG = "python -m tvrecon.robot.pybullet.pick_place"


def _run_cli(obj: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> str:
    import tvrecon.robot.pybullet.pick_place as pp

    argv = ["pick_place", f"object={obj}", f"out_dir={tmp_path / 'out'}", f"hydra.run.dir={tmp_path / 'hydra'}"]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(SystemExit) as exc:
        pp.main()
    assert exc.value.code == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{PROG}: error: "), lines
    assert not (tmp_path / "out" / "pick_place_log.npz").exists()
    return lines[0]


def test_mesh_with_a_nan_vertex_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    mesh = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    vertices = np.asarray(mesh.vertices).copy()
    vertices[0, 0] = np.nan
    path = tmp_path / "nan_box.obj"
    trimesh.Trimesh(vertices, mesh.faces, process=False).export(path)
    line = _run_cli(str(path), tmp_path, monkeypatch, capsys)
    assert str(path) in line and "NaN or infinite vertex coordinates" in line


def test_random_bytes_say_the_file_is_not_a_mesh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    path = tmp_path / "garbage.stl"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    line = _run_cli(str(path), tmp_path, monkeypatch, capsys)
    assert str(path) in line and "is not a mesh, or is truncated" in line


def test_bare_missing_mesh_file_name_says_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    line = _run_cli("mug.obj", tmp_path, monkeypatch, capsys)
    assert "object mesh file 'mug.obj' does not exist" in line and "unknown shape class" not in line


def test_unknown_class_name_still_lists_the_classes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    line = _run_cli("mugg", tmp_path, monkeypatch, capsys)
    assert "unknown shape class 'mugg'" in line and "mug" in line


def test_ctrl_c_exits_130_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import tvrecon.robot.pybullet.pick_place as pp

    def interrupted(cfg: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(pp, "run_pick_place", interrupted)
    monkeypatch.setattr(sys, "argv", ["pick_place", f"out_dir={tmp_path}", f"hydra.run.dir={tmp_path / 'hydra'}"])
    with pytest.raises(SystemExit) as exc:
        pp.main()
    assert exc.value.code == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"{PROG}: interrupted"
