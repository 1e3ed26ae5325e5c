"""`python -m tvrecon.sim press` end to end at a small resolution."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.__main__ import build_parser, main
from tvrecon.sim.press import PressConfig
from tvrecon.sim.press.reading import TactileReading

pytestmark = pytest.mark.usefixtures("one_thread")  # see tests/conftest.py


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


def test_cli_contact_and_threshold_grid_follow_the_press_defaults(capsys) -> None:
    """Without the flags the CLI presses as ``PressConfig()`` does; ``--contact grid --threshold-grid 0`` is the
    press of ``PressConfig(contact="grid", threshold_grid=None)`` (grid collider, threshold in its own cells)."""
    parse = lambda *extra: build_parser().parse_args(["press", "--out", "o", *extra])  # noqa: E731
    args = parse()
    assert (args.contact, args.threshold_grid) == (PressConfig().contact, PressConfig().threshold_grid)
    args = parse("--contact", "grid", "--threshold-grid", "0")
    assert (args.contact, args.threshold_grid) == ("grid", None)
    assert parse("--threshold-grid", "64").threshold_grid == 64
    with pytest.raises(SystemExit):
        parse("--threshold-grid", "-1")
    assert "must be >= 0" in capsys.readouterr().err


def test_cli_device_and_compile_flags(tmp_path: Path, capsys) -> None:
    """``--device`` and ``--compile`` reach the simulator; a CUDA device on a machine without one is a clear error."""
    args = build_parser().parse_args(["press", "--out", "o"])
    assert (args.device, args.compile) == ("cpu", "auto")
    out = tmp_path / "run"
    base = ["press", "--shape", "sphere", "--out", str(out), "--resolution", "6", "--layers", "3", "--n-grid", "32"]
    assert main([*base, "--depth", "0.5", "--frames", "2", "--device", "cpu", "--compile", "false"]) == 0
    assert (out / "tactile.png").is_file()
    with pytest.raises(SystemExit):
        build_parser().parse_args(["press", "--out", "o", "--compile", "fast"])
    if not torch.cuda.is_available():
        assert main([*base, "--out", str(tmp_path / "cuda"), "--device", "cuda"]) == 2
        assert "no CUDA device" in capsys.readouterr().err


def test_reading_cpu_moves_every_tensor() -> None:
    image = torch.rand(3, 4, 4)
    r = TactileReading(image, torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), 5, 1.0, 0.1, torch.ones(3), True)
    c = r.cpu()
    assert c is not r and torch.equal(c.image, image) and c.steps == 5 and c.frames is None
    assert all(t.device.type == "cpu" for t in (c.image, c.position, c.direction, c.force))


def test_cli_torus_from_the_object_library_and_bad_input(tmp_path: Path, capsys) -> None:
    args = ["press", "--shape", "torus", "--out", str(tmp_path / "t"), "--resolution", "6", "--layers", "3"]
    assert main(args + ["--n-grid", "32", "--depth", "0.5", "--frames", "2", "--ply", "1"]) == 0
    assert (tmp_path / "t" / "tactile.png").is_file()
    assert main(["press", "--shape", "nope.obj", "--out", str(tmp_path / "x")]) == 2
    assert "existing mesh file" in capsys.readouterr().err
    assert main(["press", "--shape", "sphere", "--direction", "0", "0", "0", "--out", str(tmp_path / "y")]) == 2


def test_cli_ply_zero_writes_no_ply(tmp_path: Path) -> None:
    """`--ply 0` wrote every frame's .ply (pick[-0:] is the whole list)."""
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--direction", "0", "0", "-1", "--out", str(out)]
    args += ["--resolution", "6", "--layers", "3", "--n-grid", "32", "--depth", "0.5", "--frames", "2", "--ply", "0"]
    assert main(args) == 0
    assert (out / "tactile.png").is_file()
    assert list(out.glob("pad_step*.ply")) == []


def test_cli_rejects_nan_vertices_like_the_api(tmp_path: Path, capsys) -> None:
    """The CLI pressed a mesh with a NaN vertex (trimesh dropped it) that the API rejects."""
    mesh = trimesh.creation.box()
    verts = np.asarray(mesh.vertices).copy()
    verts[0, 0] = np.nan
    path = tmp_path / "nan.obj"
    path.write_text(trimesh.Trimesh(verts, mesh.faces, process=False).export(file_type="obj"))
    args = ["press", "--shape", str(path), "--out", str(tmp_path / "o"), "--n-grid", "32", "--resolution", "6"]
    assert main(args) == 2
    assert "NaN" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frames", "0"], "--frames must be >= 1"),
        (["--ply", "-1"], "--ply must be >= 0"),
        (["--out", "FILE"], "is a file: give a folder"),
        (["--out", "FILE/sub"], "a part of its path is a file"),
        (["--out", "READONLY"], "is not writable"),
    ],
)
def test_cli_checks_outputs_before_simulating(
    extra: list[str], message: str, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bad --out or --frames 0 failed only after the whole simulation (half the files written)."""
    import tempfile

    import tvrecon.sim.__main__ as cli

    def no_simulation(*args, **kwargs):
        raise AssertionError("the simulation ran before the output options were checked")

    monkeypatch.setattr(cli, "EIPSimulator", no_simulation)
    (tmp_path / "FILE").write_text("not a folder")
    if "READONLY" in extra:  # root ignores chmod: refuse the probe like a read-only file system would

        def read_only(*args, **kwargs):
            raise PermissionError(30, "Read-only file system")

        monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
    extra = [str(tmp_path / a) if a.startswith(("FILE", "READONLY")) else a for a in extra]
    args = ["press", "--shape", "sphere", "--out", str(tmp_path / "o"), "--n-grid", "32", "--resolution", "6", *extra]
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o" / "tactile.png").exists()


def test_cli_unreadable_and_zero_size_meshes_are_clear_errors(tmp_path: Path, capsys) -> None:
    """Random bytes ended in a charset_normalizer import error, a 1e-9 mesh in ZeroDivisionError."""
    garbage = tmp_path / "garbage.obj"
    garbage.write_bytes(np.random.default_rng(0).bytes(2000))
    base = ["press", "--out", str(tmp_path / "o"), "--n-grid", "32", "--resolution", "6"]
    assert main([*base, "--shape", str(garbage)]) == 2
    err = capsys.readouterr().err
    assert str(garbage) in err and "is not a mesh, or is truncated" in err
    tiny = trimesh.creation.box()
    tiny.apply_scale(1e-9)
    path = tmp_path / "tiny.obj"
    path.write_text(tiny.export(file_type="obj"))  # 8 decimals: every vertex is written as 0
    assert main([*base, "--shape", str(path)]) == 2
    assert "has zero size" in capsys.readouterr().err


def test_cli_sensor_outputs_write_pngs(tmp_path: Path, capsys) -> None:
    """`--outputs force markers rgb` writes force.png, markers.png, rgb.png and outputs.png."""
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--direction", "0", "0", "-1", "--out", str(out), "--resolution", "8"]
    args += ["--layers", "3", "--n-grid", "32", "--depth", "0.5", "--frames", "1", "--ply", "0"]
    assert main(args + ["--outputs", "force", "markers", "rgb", "--marker-spacing", "3"]) == 0
    for name in ("force.png", "markers.png", "rgb.png", "outputs.png"):
        assert (out / name).is_file(), name
    data = np.load(out / "reading.npz")
    assert data["force_field"].shape == (8, 8, 3)
    np.testing.assert_allclose(data["force_field"].sum((0, 1)), data["frame"].T @ data["force"], rtol=1e-3, atol=1e-9)
    assert main(args + ["--outputs", "markers", "--marker-radius", "0"]) == 2
    assert "--marker-radius" in capsys.readouterr().err


def test_cli_presses_an_open_box(tmp_path: Path, capsys) -> None:
    """A box with two triangles removed, pressed with the CLI's defaults, gave contact=False."""
    box = trimesh.creation.box()
    path = tmp_path / "open_box.obj"
    path.write_text(trimesh.Trimesh(box.vertices, box.faces[:10], process=False).export(file_type="obj"))
    out = tmp_path / "o"
    args = ["press", "--shape", str(path), "--out", str(out), "--n-grid", "32", "--resolution", "8", "--layers", "3"]
    assert main(args + ["--frames", "1", "--ply", "0"]) == 0
    assert "contact=True" in capsys.readouterr().out
    data = np.load(out / "reading.npz")
    assert bool(data["contact"]) and float(data["depth"]) > 0.5 and float(data["image"][2].max()) > 0.5


def test_cli_default_press_of_pybullet_duck(tmp_path: Path, capsys) -> None:
    """The duck failed with "the pad would start inside the object" for the default direction
    (its surface rises under the pad above where the placement rays started)."""
    pybullet_data = pytest.importorskip("pybullet_data")
    duck = Path(pybullet_data.getDataPath()) / "duck.obj"
    if not duck.is_file():
        pytest.skip("pybullet_data has no duck.obj")
    out = tmp_path / "o"
    args = ["press", "--shape", str(duck), "--out", str(out), "--n-grid", "64", "--resolution", "32", "--layers", "2"]
    assert main(args + ["--depth", "0.5", "--frames", "1", "--ply", "0"]) == 0
    assert "contact=True" in capsys.readouterr().out
