"""`python -m tvrecon.sim press` end to end at a small resolution."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.__main__ import main


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_cli_press_writes_all_files(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--direction", "0", "0", "-1", "--out", str(out)]
    args += ["--resolution", "8", "--layers", "4", "--n-grid", "32", "--depth", "1.0", "--frames", "3", "--surface"]
    assert main(args) == 0
    for name in ("tactile.png", "reading.npz", "deformation.png", "pad_surface.ply"):
        assert (out / name).is_file(), name
    assert len(list(out.glob("pad_step*.ply"))) == 3
    data = np.load(out / "reading.npz")
    assert data["image"].shape == (3, 8, 8)
    assert bool(data["contact"]) and float(data["depth"]) == pytest.approx(1.0, abs=0.1)
    np.testing.assert_allclose(data["direction"], [0.0, 0.0, -1.0], atol=1e-6)


def test_cli_torus_from_the_object_library_and_bad_input(tmp_path: Path, capsys) -> None:
    args = ["press", "--shape", "torus", "--out", str(tmp_path / "t"), "--resolution", "6", "--layers", "3"]
    assert main(args + ["--n-grid", "32", "--depth", "0.5", "--frames", "2", "--ply", "1"]) == 0
    assert (tmp_path / "t" / "tactile.png").is_file()
    assert main(["press", "--shape", "nope.obj", "--out", str(tmp_path / "x")]) == 2
    assert "existing mesh file" in capsys.readouterr().err
    assert main(["press", "--shape", "sphere", "--direction", "0", "0", "0", "--out", str(tmp_path / "y")]) == 2


def test_cli_ply_zero_writes_no_ply(tmp_path: Path) -> None:
    """Issue 14 case 5: `--ply 0` wrote every frame's .ply (pick[-0:] is the whole list)."""
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--direction", "0", "0", "-1", "--out", str(out)]
    args += ["--resolution", "6", "--layers", "3", "--n-grid", "32", "--depth", "0.5", "--frames", "2", "--ply", "0"]
    assert main(args) == 0
    assert (out / "tactile.png").is_file()
    assert list(out.glob("pad_step*.ply")) == []


def test_cli_rejects_nan_vertices_like_the_api(tmp_path: Path, capsys) -> None:
    """Issue 14 case 2: the CLI pressed a mesh with a NaN vertex (trimesh dropped it) that the API rejects."""
    mesh = trimesh.creation.box()
    verts = np.asarray(mesh.vertices).copy()
    verts[0, 0] = np.nan
    path = tmp_path / "nan.obj"
    path.write_text(trimesh.Trimesh(verts, mesh.faces, process=False).export(file_type="obj"))
    args = ["press", "--shape", str(path), "--out", str(tmp_path / "o"), "--n-grid", "32", "--resolution", "6"]
    assert main(args) == 2
    assert "NaN" in capsys.readouterr().err
