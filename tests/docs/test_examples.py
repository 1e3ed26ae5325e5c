"""Every script of examples/ runs at a tiny size and writes what its docstring promises.

Each runs as a user runs it (a subprocess from the repository root), on one thread, into the test's folder.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def _run(argv: list[str], tmp_path: Path, timeout: int = 400, **env: str) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg", **env}
    return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=full_env)


def test_every_example_is_tested() -> None:
    scripts = sorted(p.name for p in EXAMPLES.iterdir() if p.suffix in {".py", ".sh"})
    assert scripts == ["classify_touches.py", "press_my_mesh.py", "reproduce_table3.sh", "robot_mujoco_pad.py"]


@pytest.fixture()
def block_mm(tmp_path: Path) -> Path:
    """A 40 x 30 x 20 mm block off the origin, as a CAD export in millimetres."""
    block = trimesh.creation.box(extents=(40.0, 30.0, 20.0))
    block.apply_translation((100.0, 50.0, 10.0))
    path = tmp_path / "block_mm.stl"
    block.export(path)
    return path


def test_press_my_mesh_in_millimetres(block_mm: Path, tmp_path: Path) -> None:
    out = tmp_path / "press"
    argv = [sys.executable, str(EXAMPLES / "press_my_mesh.py"), str(block_mm), "--units", "mm", "--sensor", "digit"]
    argv += ["--position", "100", "50", "20", "--direction", "0", "0", "-1", "--depth-mm", "0.8", "--n-grid", "48"]
    done = _run([*argv, "--out", str(out)], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    for name in ("tactile.png", "force.png", "force_field.npy", "contact_patch.ply", "contact_patch.npz"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["contact"] and summary["force_N"][2] > 0 and summary["taxels_in_contact"] > 0
    assert summary["depth_mm"] == pytest.approx(0.8, abs=summary["cell_mm"] * 0.3)
    patch = np.load(out / "contact_patch.npz")
    touched = patch["points"][patch["mask"]]  # in the file's millimetres: on the block's top face, under the pad
    assert np.abs(touched[:, 2] - 20.0).max() < summary["cell_mm"]
    assert np.abs(touched[:, :2] - (100.0, 50.0)).max() < 12.0
    field = np.load(out / "force_field.npy")  # (H, W, 3) newtons, sensor frame
    assert field[..., 2].sum() == pytest.approx(summary["force_N"][2], rel=1e-3)


def test_press_my_mesh_names_a_missing_file(tmp_path: Path) -> None:
    done = _run([sys.executable, str(EXAMPLES / "press_my_mesh.py"), str(tmp_path / "none.stl")], tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("press_my_mesh.py: error: mesh file")


def test_robot_mujoco_pad(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    out = tmp_path / "pad"
    argv = [sys.executable, str(EXAMPLES / "robot_mujoco_pad.py"), "--object", "box", "--steps", "60"]
    done = _run([*argv, "--resolution", "8", "--n-grid", "32", "--out", str(out)], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["contact"] and summary["force_N"] > 0 and summary["max_normal_cells"] > 0
    assert (out / "tactile.png").is_file() and (out / "rgb.png").is_file()
    forces = (out / "force_N.csv").read_text().splitlines()
    assert len(forces) == 61 and float(forces[1].split(",")[1]) == 0.0  # no contact at the start, 60 steps logged


@pytest.mark.slow
def test_classify_touches(tmp_path: Path) -> None:
    run = tmp_path / "run"
    train = [sys.executable, "train.py", "experiment=classify", "data=cls_tiny", "model.num_touches=2"]
    train += ["trainer.max_epochs=1", "tables=false", "torch_threads=1", f"hydra.run.dir={run}"]
    done = _run([*train, f"paths.cache_dir={tmp_path / 'cache'}"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    done = _run([sys.executable, str(EXAMPLES / "classify_touches.py"), "--run", str(run), "--objects", "2"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 3 and lines[0].startswith("test object   0 (") and "2 touches:" in lines[0]
    assert lines[-1].startswith("accuracy: ") and "/2 = " in lines[-1]


@pytest.mark.slow
def test_reproduce_table3_tiny(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    done = _run(["bash", str(EXAMPLES / "reproduce_table3.sh"), "--tiny"], tmp_path, timeout=600,
                PY=sys.executable, LOG_DIR=str(logs), CACHE_DIR=str(tmp_path / "cache"))
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Table 3" in done.stdout and "Tables 3 and 4: " in done.stdout
    runs = sorted(p.parent.name for p in (logs / "train" / "multiruns").glob("table3_tiny_*/*/metrics.json"))
    assert runs == ["0_chart_based", "0_full", "1_chart_based_visual", "1_visual_only"]
    # one eval prints both of the paper's Table 3 rows, each assembled from its own runs
    assert "Ours (paper layout)" in done.stdout and "Chart-based (paper layout)" in done.stdout
    assert any((logs / "eval").rglob("table3.md"))
