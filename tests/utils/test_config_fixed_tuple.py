"""A fixed-length tuple field of a config (``place_xy: tuple[float, float]``) refuses another length or a non-number,
naming the field and the value, when the config is built (not at the end of a robot episode)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from tvrecon.utils.config_utils import coerce_config


@dataclass
class _Demo:
    place_xy: tuple[float, float] = (0.5, 0.15)
    size: tuple[int, int] | None = None
    tags: tuple[str, ...] = ()


def test_fixed_tuples_are_checked_by_name() -> None:
    assert coerce_config(_Demo, {"place_xy": [0.4, 0.1], "size": [2, 3], "tags": ["a", "b", "c"]}).size == (2, 3)
    assert coerce_config(_Demo, {"size": None}).size is None
    with pytest.raises(ValueError, match=r"^place_xy must hold 2 values \(demo config\), got 1: \[0.5\]$"):
        coerce_config(_Demo, {"place_xy": [0.5]}, "demo")
    with pytest.raises(TypeError, match=r"^size \(demo config\) \[2, 'x'\]: each value must be a number, got 'x'"):
        coerce_config(_Demo, {"size": [2, "x"]}, "demo")


def test_the_robot_configs_name_place_xy() -> None:
    from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig

    with pytest.raises(ValueError, match=r"^place_xy must hold 2 values \(pick_place config\), got 1: \[0.5\]"):
        PickPlaceConfig.from_dict({"place_xy": [0.5]})
    mujoco_config = pytest.importorskip("tvrecon.robot.mujoco.pick_place_config")
    with pytest.raises(ValueError, match=r"^object_xy must hold 2 values \(scene config\), got 3"):
        mujoco_config.MujocoPickPlaceConfig.from_dict({"scene": {"object_xy": [0.5, 0.1, 0.0]}})
