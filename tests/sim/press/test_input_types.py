"""API arguments of the wrong type name the argument; counts and grid sizes are whole numbers.

Before: ``SensorConfig(resolution=64)`` failed on "'int' object is not iterable", ``E='3'`` was taken as 3.0,
a dict for ``sensor`` or the ``PressConfig`` class instead of an instance failed deep inside the press, and
``PressConfig(n_grid=40.7)`` was kept as 40.7.
"""

from __future__ import annotations

import pytest
import torch

from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig
from tvrecon.utils.config_utils import check_whole


@pytest.mark.parametrize(
    ("build", "error", "match"),
    [
        (lambda: SensorConfig(resolution=64), TypeError, r"SensorConfig.resolution must be \(H, W\), e.g. \(64, 64\)"),
        (lambda: SensorConfig(resolution=(8.5, 8)), ValueError, "SensorConfig.resolution must be a whole number"),
        (lambda: SensorConfig(E="3"), TypeError, r"SensorConfig.E must be a number, got '3' \(str\)"),
        (lambda: SensorConfig(nu=None), TypeError, "SensorConfig.nu must be a number"),
        (lambda: SensorConfig(layers=6.5), ValueError, "SensorConfig.layers must be a whole number, got 6.5"),
        (lambda: PressConfig(n_grid=40.7), ValueError, "PressConfig.n_grid must be a whole number, got 40.7"),
        (lambda: PressConfig(n_grid="64"), TypeError, "PressConfig.n_grid must be a whole number, got '64'"),
        (lambda: PressConfig(max_steps=10.5), ValueError, "PressConfig.max_steps must be a whole number"),
        (lambda: PressConfig(depth="1"), TypeError, "PressConfig.depth must be a number"),
        (lambda: EIPSimulator(sensor={"E": 3.0}), TypeError, r"sensor must be a SensorConfig, got dict.*\*\*mapping"),
        (lambda: EIPSimulator(press=PressConfig), TypeError, r"press must be a PressConfig instance, got the class"),
        (lambda: EIPSimulator(press=SensorConfig()), TypeError, "press must be a PressConfig, got SensorConfig"),
    ],
)
def test_wrong_types_name_the_argument(build, error, match) -> None:
    with pytest.raises(error, match=match):
        build()


def test_right_types_still_pass() -> None:
    assert SensorConfig(resolution=[8, 8]).resolution == (8, 8)
    assert SensorConfig(resolution=(8.0, 8)).resolution == (8, 8)
    SensorConfig(E=torch.tensor(3.0, requires_grad=True))  # differentiable material parameters
    PressConfig(n_grid=40.0, max_steps=10)
    EIPSimulator(SensorConfig(), PressConfig())


def test_check_whole() -> None:
    assert check_whole(3, "n") == 3 and check_whole(3.0, "n") == 3
    with pytest.raises(ValueError, match="n must be >= 1, got 0"):
        check_whole(0, "n", minimum=1)
    for bad in (True, None, "3", [3]):
        with pytest.raises(TypeError, match="n must be a whole number"):
            check_whole(bad, "n")
