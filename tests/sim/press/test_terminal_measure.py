"""``PressConfig.terminal="displacement"``: the terminal threshold on the particle-matched deformation.

On a face larger than the pad the deformation is a sideways spread, which eq. 12's nearest neighbours stop seeing
past half a lattice spacing: the displacement stop comes first there. On a sphere the deformation is a normal dent
and both stop on the same step (docs/notes/stop-depth.md).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tvrecon.data.cache.store import cache_key, canonical_json
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.stop_rules import threshold_cells
from tvrecon.sim.sensor.elastic_pad import SensorConfig


def _press(mesh: trimesh.Trimesh, top: float, terminal: str):
    pad = SensorConfig(resolution=(32, 32), layers=5, spacing=0.5)  # 1/4 of the domain wide, 1/32 thick at n_grid 64
    p = PressConfig(n_grid=64, threshold=0.4, terminal=terminal)
    return EIPSimulator(pad, p).press(mesh, [0.0, 0.0, top], [0.0, 0.0, -1.0]), threshold_cells(p)


def test_displacement_stop_comes_first_on_a_flat_face_and_with_the_chamfer_on_a_dent() -> None:
    cube = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
    chamfer, thr = _press(cube, 0.4, "chamfer")
    matched, _ = _press(cube, 0.4, "displacement")
    assert chamfer.chamfer >= thr and chamfer.depth > 2.0  # the cube's face is under the whole pad: a deep stop
    assert matched.steps < chamfer.steps  # 3.02 vs 3.14 cells when written
    assert matched.chamfer < thr  # the reading still carries eq. 12, below its threshold at this stop
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    dent_c, _ = _press(ball, 0.3, "chamfer")
    dent_m, _ = _press(ball, 0.3, "displacement")
    assert dent_m.steps == dent_c.steps
    np.testing.assert_allclose(dent_m.image.numpy(), dent_c.image.numpy())


def test_terminal_must_be_a_known_measure_and_enters_the_cache_key_only_off_its_default() -> None:
    with pytest.raises(ValueError, match="PressConfig.terminal"):
        PressConfig(terminal="hausdorff")
    assert "terminal" not in canonical_json({"press": PressConfig()})  # cached data keeps its keys
    assert cache_key({"press": PressConfig(terminal="displacement")}) != cache_key({"press": PressConfig()})


def test_cli_takes_the_terminal_measure(tmp_path, monkeypatch) -> None:
    import tvrecon.sim.__main__ as cli

    seen: list[PressConfig] = []

    class Spy(EIPSimulator):
        def __init__(self, sensor=None, press=None, **kw) -> None:
            seen.append(press)
            super().__init__(sensor, press, **kw)

    monkeypatch.setattr(cli, "EIPSimulator", Spy)
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--out", str(out), "--resolution", "8", "--layers", "4", "--n-grid", "32"]
    assert cli.main(args + ["--terminal", "displacement", "--frames", "2", "--ply", "0"]) == 0
    assert [p.terminal for p in seen] == ["displacement"]
    data = np.load(out / "reading.npz")
    assert bool(data["contact"]) and float(data["image"][2].max()) > 0
