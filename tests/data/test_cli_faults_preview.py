"""The preview CLI follows the one CLI vocabulary: --shape is any class or a mesh file, output under outputs/."""

from __future__ import annotations

from pathlib import Path

import trimesh

from tvrecon.data.preview import main
from tvrecon.utils.cli_errors import call_cli

FAST = ["--pad", "8", "--n-grid", "32", "--touches", "1", "--image-size", "32"]


def test_preview_of_a_mesh_file_goes_under_outputs(tmp_path: Path, monkeypatch, capsys) -> None:
    part = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    part.export(tmp_path / "part.stl")
    monkeypatch.chdir(tmp_path)
    assert call_cli(main, ["--shape", "part.stl", *FAST], prog="preview") == 0
    [png] = list((tmp_path / "outputs" / "preview").glob("*/preview.png"))
    assert capsys.readouterr().out.strip().splitlines()[-1] == f"outputs in {png.parent.resolve()}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outputs", "part.stl"]


def test_preview_names_an_unknown_shape(tmp_path: Path, capsys) -> None:
    assert call_cli(main, ["--shape", "mugg", "--out", str(tmp_path / "p.png"), *FAST], prog="preview") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("preview: error: shape 'mugg' is neither an object class nor an existing mesh file")
    assert "\n" not in err
