"""Figures: loss curves from a CSV log, mesh renders and .obj export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.models.mesh_figures import export_obj, render_mesh_comparison
from tvrecon.report.viz import plot_loss_curves, read_metrics_csv


def test_loss_curves_from_lightning_csv(tmp_path: Path) -> None:
    csv = tmp_path / "metrics.csv"
    csv.write_text(
        "epoch,lr-AdamW,step,train/loss,train/chamfer,val/loss,val/chamfer\n"
        "0,,0,1.0,0.5,,\n0,,1,0.8,0.4,,\n0,,1,,,0.9,30.0\n0,0.001,1,,,,\n1,,2,0.5,0.2,,\n1,,3,0.4,0.1,0.6,20.0\n"
    )
    series = read_metrics_csv(csv)
    assert series["train/loss"] == [(0.0, 1.0), (1.0, 0.8), (2.0, 0.5), (3.0, 0.4)]
    assert series["val/chamfer"] == [(1.0, 30.0), (3.0, 20.0)]
    out = plot_loss_curves(csv, tmp_path / "curves.png")
    assert out.is_file() and out.stat().st_size > 1000
    with pytest.raises(ValueError, match="does not exist"):
        plot_loss_curves(tmp_path / "missing.csv", tmp_path / "x.png")
    (tmp_path / "empty.csv").write_text("epoch,step\n0,0\n")
    with pytest.raises(ValueError, match="no train/\\* or val/\\* values"):
        plot_loss_curves(tmp_path / "empty.csv", tmp_path / "x.png")


def test_render_and_export_roundtrip(tmp_path: Path) -> None:
    box = trimesh.creation.box((0.4, 0.3, 0.2))
    verts = torch.tensor(box.vertices, dtype=torch.float32) + torch.tensor([0.0, 0.0, 2.0])
    faces = torch.tensor(box.faces, dtype=torch.int64)
    png = render_mesh_comparison(verts, faces, verts[:5], tmp_path / "r" / "cmp.png", "box", torch.rand(3, 16, 16))
    assert png.is_file() and not list(png.parent.glob(".*"))
    obj = export_obj(verts, faces, tmp_path / "m" / "box.obj")
    assert obj.stat().st_mode & 0o644 == 0o644  # readable like a plain open(), not mkstemp's 0o600
    back = trimesh.load(obj, process=False)
    assert np.allclose(back.vertices, verts.numpy(), atol=1e-6) and np.array_equal(back.faces, faces.numpy())
    with pytest.raises(ValueError, match=r"pred_faces index outside"):
        render_mesh_comparison(verts, faces + 100, verts, tmp_path / "bad.png")
    with pytest.raises(ValueError, match=r"gt_points must have shape \(N, 3\)"):
        render_mesh_comparison(verts, faces, verts[:, :2], tmp_path / "bad.png")
    with pytest.raises(ValueError, match=r"\.obj"):
        export_obj(verts, faces, tmp_path / "box.ply")


def test_renders_close_their_figures(tmp_path) -> None:
    import matplotlib.pyplot as plt
    import numpy as np

    from tvrecon.models.mesh_figures import render_mesh_comparison

    verts = np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.0, 0.1, 2.0], [0.0, 0.0, 2.1]])
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    before = len(plt.get_fignums())
    for k in range(3):
        render_mesh_comparison(verts, faces, verts, tmp_path / f"r{k}.png")
    assert len(plt.get_fignums()) == before


def test_run_comparison_overlays_runs(tmp_path: Path, capsys) -> None:
    from tvrecon.report.viz import find_metrics_csv, main, plot_run_comparison

    for name, scale in (("a", 1.0), ("b", 2.0)):
        (tmp_path / name / "csv").mkdir(parents=True)
        (tmp_path / name / "csv" / "metrics.csv").write_text(
            "epoch,step,train/loss,val/chamfer\n"
            f"0,0,{scale},\n0,14,,{30 * scale}\n1,15,{scale / 2},\n1,29,,{20 * scale}\n"
        )
    assert find_metrics_csv(tmp_path / "a") == tmp_path / "a" / "csv" / "metrics.csv"
    out = plot_run_comparison({"a": tmp_path / "a", "b": tmp_path / "b" / "csv" / "metrics.csv"}, tmp_path / "c.png")
    assert out.is_file() and out.stat().st_size > 1000
    with pytest.raises(ValueError, match="no run logged 'val/fscore'"):
        plot_run_comparison({"a": tmp_path / "a"}, tmp_path / "x.png", ["val/fscore"])
    with pytest.raises(ValueError, match="no metrics.csv below"):
        find_metrics_csv(tmp_path / "missing")
    assert main(["compare", f"a={tmp_path / 'a'}", f"b={tmp_path / 'b'}", "--out", str(tmp_path / "d.png")]) == 0
    assert (tmp_path / "d.png").is_file() and "wrote" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["compare", str(tmp_path / "a"), "--out", str(tmp_path / "e.png")])  # no LABEL=
    assert "LABEL=RUN_DIR" in capsys.readouterr().err



def test_run_comparison_without_out_writes_under_outputs(tmp_path: Path, monkeypatch, capsys) -> None:
    from tvrecon.report.viz import main

    (tmp_path / "a" / "csv").mkdir(parents=True)
    (tmp_path / "a" / "csv" / "metrics.csv").write_text("epoch,step,train/loss,val/chamfer\n0,0,1.0,\n0,9,,30\n")
    monkeypatch.chdir(tmp_path)
    assert main(["compare", "a=a"]) == 0
    (png,) = (tmp_path / "outputs" / "compare").glob("*/compare.png")
    assert png.stat().st_size > 1000 and f"outputs in {png.parent}" in capsys.readouterr().out
