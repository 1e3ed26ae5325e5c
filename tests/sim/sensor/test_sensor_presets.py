"""Sensor presets (tvrecon.sim.sensor.presets): pads that fit the domain, their Hydra blocks, a tiny press each."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
import yaml
from omegaconf import OmegaConf

from tvrecon.sim.__main__ import main
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig
from tvrecon.sim.sensor.presets import (
    NU_SIM,
    SENSOR_PRESETS,
    pad_fits,
    press_overrides,
    sensor_config,
    speed_fraction_for,
)

NAMES = sorted(SENSOR_PRESETS)
SENSOR_BLOCKS = Path(__file__).resolve().parents[3] / "configs" / "data" / "sensor"


pytestmark = pytest.mark.usefixtures("one_thread")  # see tests/conftest.py


def test_the_common_sensors_are_there() -> None:
    assert {"gelsight_mini", "digit", "gelsight_r15", "tactip"} <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("n_grid", [32, 64, 128])
def test_preset_builds_a_pad_of_the_sensor_size_that_fits(name: str, n_grid: int) -> None:
    p = SENSOR_PRESETS[name]
    s = sensor_config(name, n_grid)
    assert isinstance(s, SensorConfig) and s.nu == pytest.approx(min(p.nu, NU_SIM))
    assert s.E == pytest.approx(p.E_kPa / 100.0)  # 1 stress unit = 100 kPa
    H, W = s.resolution
    mm = p.cell_mm(n_grid) * s.spacing  # mm between particles
    # the contact layer covers the sensing area and the layers the gel, to within one particle
    assert abs(W * mm - p.width_mm) <= mm and abs(H * mm - p.height_mm) <= mm
    assert abs(s.thickness * p.cell_mm(n_grid) - p.thickness_mm) <= mm
    assert max(H, W) * s.spacing == pytest.approx(0.25 * n_grid, abs=s.spacing)  # longer side = fill * n_grid cells
    assert pad_fits(s, n_grid)


@pytest.mark.parametrize("name", NAMES)
def test_hydra_block_loads_the_preset_at_n_grid_128(name: str) -> None:
    """A data preset with ``data/sensor=<name>`` builds the preset's pad: the block reads every number of it from
    :mod:`tvrecon.sim.sensor.presets` (``${sensor_preset:...}``) and holds none of its own."""
    from tvrecon.data.presets import compose_preset
    from tvrecon.utils.config_utils import coerce_config

    block = yaml.safe_load((SENSOR_BLOCKS / f"{name}.yaml").read_text())
    assert block["defaults"] == ["gel", "_self_"]
    assert {k: v for k, v in block.items() if k != "defaults"} == {
        field: f"${{sensor_preset:{name},{field}}}" for field in ("resolution", "layers", "E", "nu")
    }
    cfg = compose_preset("tiny", [f"sensor={name}"])
    sensor = coerce_config(SensorConfig, OmegaConf.to_container(cfg.sensor, resolve=True), "sensor")
    assert sensor == sensor_config(name, 128)


def test_speed_keeps_the_default_ratio_to_the_shear_wave() -> None:
    assert speed_fraction_for(0.25) == pytest.approx(0.1)
    # hand speed / shear-wave speed = speed_fraction * c_p / c_s, with c_s / c_p = sqrt((1 - 2 nu) / (2 (1 - nu)))
    ref = 0.1 / math.sqrt(0.5 / 1.5)  # the default: 0.17 of the shear-wave speed
    assert speed_fraction_for(0.45) / math.sqrt(0.1 / 1.1) == pytest.approx(ref)
    over = press_overrides("digit", 128)
    assert over["domain_size"] == pytest.approx(128 * 19.0 / 32)  # 19 mm over 32 cells
    PressConfig(n_grid=128, **over)  # valid press fields


def test_unknown_preset_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="gelsight_mini"):
        sensor_config("nope")


@pytest.mark.parametrize("name", NAMES)
def test_tiny_press_with_each_preset(name: str) -> None:
    """n_grid 32: the pads are 8 cells wide, 1-5 cells thick (<= 1536 particles); a 1-cell press on a sphere."""
    s = sensor_config(name, 32)
    press = PressConfig(n_grid=32, depth=1.0, speed_fraction=press_overrides(name, 32)["speed_fraction"])
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    t0 = time.perf_counter()
    r = EIPSimulator(s, press).press(mesh, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0])
    assert time.perf_counter() - t0 < 5.0  # ~1 s on one thread
    assert r.contact and r.depth == pytest.approx(1.0, abs=0.15)
    assert r.image.shape == (3, *s.resolution) and bool(torch.isfinite(r.image).all())
    assert float(r.image[2].max()) > 0.2  # the pad is pushed in (cells)
    assert float(r.force[2].abs()) > 0


def test_cli_sensor_flag(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run"
    args = ["press", "--shape", "sphere", "--sensor", "digit", "--n-grid", "32", "--depth", "0.5"]
    assert main(args + ["--out", str(out), "--frames", "2", "--ply", "0"]) == 0
    text = capsys.readouterr().out
    assert "sensor DIGIT: 16x13 pad, 4 layers" in text and "1 cell = 2.375 mm" in text
    assert np.load(out / "reading.npz")["image"].shape == (3, 13, 16)
    # explicit flags still override the preset
    assert main(args + ["--out", str(tmp_path / "o"), "--resolution", "6", "--layers", "3", "--ply", "0"]) == 0
    assert np.load(tmp_path / "o" / "reading.npz")["image"].shape == (3, 6, 6)
