"""The press CLI speaks the project's one vocabulary: ``--shape`` takes any object class or a mesh file, output goes
to ``--out`` or ``outputs/sim_press/<time>/`` (printed), a second press replaces the first's files, and the
simulator's API names the argument a string or a tensor without values was given for."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import trimesh

from tvrecon.data.shapes import available_classes
from tvrecon.sim import EIPSimulator
from tvrecon.sim.__main__ import load_shape, main
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig

SMALL = ["--n-grid", "32", "--resolution", "6", "--layers", "3", "--depth", "0.5", "--frames", "2", "--threads", "1"]


def test_every_object_class_is_a_shape() -> None:
    for cls in available_classes():
        mesh = load_shape(cls)
        assert mesh.is_watertight and abs(float(mesh.extents.max()) - 1.0) < 1e-6, cls
    assert load_shape("sphere").vertices.shape == load_shape("ball").vertices.shape  # the alias
    with pytest.raises(ValueError, match=r"--shape 'mugg' is neither an object class nor an existing mesh file; "):
        load_shape("mugg")


def test_without_out_the_press_goes_under_outputs_and_says_where(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["press", "--shape", "mug", *SMALL]) == 0
    [run] = list((tmp_path / "outputs" / "sim_press").iterdir())
    assert (run / "tactile.png").is_file() and (run / "reading.npz").is_file()
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1] == f"outputs in {run.resolve()}"
    assert "wrote tactile.png" in out and "wrote ply" not in out  # files named plainly
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outputs"]  # nothing else in the current folder


def test_a_second_press_into_one_out_replaces_the_first(tmp_path: Path, capsys) -> None:
    out = tmp_path / "o"
    assert main(["press", "--shape", "sphere", *SMALL, "--ply", "2", "--out", str(out)]) == 0
    first = sorted(p.name for p in out.glob("pad_step*.ply"))
    assert len(first) == 2
    capsys.readouterr()
    assert main(["press", "--shape", "sphere", *SMALL[:-6], "--depth", "0.25", "--frames", "3", "--ply", "1",
                 "--out", str(out)]) == 0  # fmt: skip
    second = sorted(p.name for p in out.glob("pad_step*.ply"))
    assert len(second) == 1 and "held an earlier press: its files are replaced" in capsys.readouterr().out


def test_the_smallest_grid_says_which_grid_fits(capsys, tmp_path: Path) -> None:
    assert main(["press", "--shape", "torus", "--n-grid", "16", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "does not fit in the domain of n_grid=16 (the smallest that fits it is 24)" in err


@pytest.fixture(scope="module")
def sim() -> EIPSimulator:
    return EIPSimulator(SensorConfig(resolution=(6, 6), layers=3), PressConfig(n_grid=32, depth=0.5))


def test_press_names_a_string_position_or_direction(sim: EIPSimulator) -> None:
    ball = trimesh.creation.icosphere(radius=0.5)
    with pytest.raises(TypeError, match=r"^position must be numbers of shape \(3,\), e.g. \[0, 0, -1\]; got the "):
        sim.press(ball, "0 0 0.3", [0.0, 0.0, -1.0])
    with pytest.raises(TypeError, match=r"^direction must be numbers of shape \(3,\).*got the string 'down'"):
        sim.press(ball, None, "down")
    with pytest.raises(TypeError, match=r"^directions must be numbers of shape \(T, 3\)"):
        sim.press_batch(ball, [[0.0, 0.0, 0.5]], ["0 0 -1"])


def test_press_batch_takes_points_from_any_device_and_names_a_meta_tensor(sim: EIPSimulator) -> None:
    ball = trimesh.creation.icosphere(radius=0.5)
    with pytest.raises(TypeError, match=r"^positions is a tensor on the meta device"):
        sim.press_batch(ball, [torch.zeros(3), torch.zeros(3, device="meta")], [[0.0, 0.0, -1.0]] * 2)
    mixed = [torch.tensor([0.0, 0.0, 0.5]), torch.tensor([0.0, 0.0, 0.5], dtype=torch.float64)]
    readings = sim.press_batch(ball, mixed, torch.tensor([[0.0, 0.0, -1.0]] * 2))
    assert [bool(r.contact) for r in readings] == [True, True]
