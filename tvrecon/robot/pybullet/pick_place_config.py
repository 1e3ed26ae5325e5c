"""The configuration of the pybullet pick-and-place demo (:mod:`tvrecon.robot.pybullet.pick_place`), read by its arm
controller too (:mod:`tvrecon.robot.pybullet.controller`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from tvrecon.robot.pick_place_common import PickPlaceSettings
from tvrecon.robot.pybullet.camera import CameraConfig
from tvrecon.robot.pybullet.scene import SceneConfig
from tvrecon.utils.config_utils import coerce_config

__all__ = ["PickPlaceConfig"]


@dataclass
class PickPlaceConfig(PickPlaceSettings):
    """Everything the pybullet demo needs (mirrors ``configs/robot/pick_place.yaml``): the shared settings
    (:class:`~tvrecon.robot.pick_place_common.PickPlaceSettings`) and these.

    close_speed: m/s of the fingers closing. squeeze_steps / settle_steps: simulation steps. frame_every: simulation
    steps per logged frame.
    """

    close_speed: float = 0.05
    squeeze_steps: int = 90
    settle_steps: int = 40
    frame_every: int = 8
    render_eye: tuple[float, float, float] = (0.98, 0.0, 0.86)
    render_target: tuple[float, float, float] = (0.47, 0.0, 0.69)
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)

    @classmethod
    def from_dict(cls, d: dict) -> PickPlaceConfig:
        """Build from a plain (Hydra/OmegaConf container) dict; nested dicts fill the nested dataclasses."""
        return coerce_config(cls, d, "pick_place")
