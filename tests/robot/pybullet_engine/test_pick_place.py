"""The pick-and-place task: config composition, object loading, failure reporting (no EIP press needed)."""

from pathlib import Path

import numpy as np
import pytest
import trimesh
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from tvrecon.robot.pick_place_common import PHASES, load_object_mesh
from tvrecon.robot.pybullet.pick_place import run_pick_place
from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig

CONFIG_DIR = str(Path(__file__).resolve().parents[3] / "configs" / "robot")


def test_hydra_config_composes_into_dataclass() -> None:
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        dcfg = compose("pick_place", overrides=["object=cube", "scene.object_size=0.12", "pad.resolution=[16,16]"])
    cfg = PickPlaceConfig.from_dict(OmegaConf.to_container(dcfg, resolve=True))
    assert cfg.object == "cube"
    assert cfg.scene.object_size == pytest.approx(0.12)
    assert cfg.pad.resolution == (16, 16)
    assert cfg.place_xy == (0.5, 0.15)
    with pytest.raises(ValueError, match="unknown pick_place option"):
        PickPlaceConfig.from_dict({"objekt": "can"})
    with pytest.raises(ValueError, match="unknown pad option"):
        PickPlaceConfig.from_dict({"pad": {"size": 0.02}})


def test_load_object_mesh_class_and_file(tmp_path) -> None:
    cube = load_object_mesh("cube")
    assert isinstance(cube, trimesh.Trimesh) and max(cube.extents) == pytest.approx(1.0, abs=1e-6)
    path = tmp_path / "thing.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=3.0).export(path)
    user = load_object_mesh(str(path))
    assert max(user.extents) == pytest.approx(6.0, rel=1e-3)
    with pytest.raises(ValueError, match="does not exist"):
        load_object_mesh(str(tmp_path / "missing.obj"))


def test_too_wide_object_is_reported_and_logged(tmp_path) -> None:
    """A 12 cm box cannot fit in the Panda's 8 cm opening: clear message, no motion, log still written."""
    cfg = PickPlaceConfig(object="cube", out_dir=str(tmp_path), render_size=(96, 72), progress=False)
    cfg.scene.object_size = 0.12
    res = run_pick_place(cfg)
    assert not res.success
    assert "too wide" in res.message and "8.0 cm" in res.message
    assert res.num_presses == 0
    assert res.log_path is not None and res.log_path.exists()
    log = np.load(res.log_path)
    assert not bool(log["success"]) and "too wide" in str(log["message"])
    assert log["tactile"].shape[1:3] == (2, 3) and not log["contact"].any()
    assert float(log["grasp_width"]) > 0.1
    assert res.strip_path is not None and res.strip_path.exists()
    assert list(log["phase_names"]) == list(PHASES)


def test_oversized_object_is_reported_as_thrown_out_not_too_small(tmp_path) -> None:
    """``scene.object_size=2.0`` knocked the object out of the scene; the robot said "too small"."""
    cfg = PickPlaceConfig(object="can", out_dir=str(tmp_path), render_size=(48, 36), progress=False)
    cfg.scene.object_size = 2.0
    cfg.write_gif = cfg.write_mp4 = False
    res = run_pick_place(cfg)
    assert not res.success and res.num_presses == 0
    assert "did not stay where it was put down" in res.message and "scene.object_size=2.0" in res.message
    assert "too small" not in res.message
    assert res.log_path is not None and "object_size=2.0" in str(np.load(res.log_path)["message"])


@pytest.mark.parametrize("success", [True, False])
def test_cli_exit_status_follows_the_outcome(success: bool, tmp_path, monkeypatch, capsys) -> None:
    """The robot CLI exited 0 after printing [FAILED]; scripts could not tell."""
    import sys
    from types import SimpleNamespace

    import tvrecon.robot.pybullet.pick_place as pp

    fake = SimpleNamespace(
        success=success, message="fake", log_path=None, gif_path=None, mp4_path=None, strip_path=None,
        wall_time=0.0, num_presses=0, log={},
    )  # fmt: skip
    monkeypatch.setattr(pp, "run_pick_place", lambda cfg: fake)
    monkeypatch.setattr(sys, "argv", ["pick_place", f"out_dir={tmp_path}", f"hydra.run.dir={tmp_path / 'hydra'}"])
    if success:
        pp.main()
    else:
        with pytest.raises(SystemExit) as exc:
            pp.main()
        assert exc.value.code == 1
    assert ("[OK] fake" if success else "[FAILED] fake") in capsys.readouterr().out
