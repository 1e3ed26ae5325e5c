"""The configuration of the MuJoCo pick-and-place demo (:mod:`tvrecon.robot.mujoco.pick_place`), its outcome, and
the object it names (a library class, a ``pybullet_data`` mesh or a mesh file)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tvrecon.robot.grasp import GraspPlan
from tvrecon.robot.mujoco.scene import MujocoSceneConfig
from tvrecon.robot.pick_place_common import PickPlaceSettings
from tvrecon.utils.config_utils import coerce_config

__all__ = ["MujocoCameraConfig", "MujocoPickPlaceConfig", "MujocoPickPlaceResult"]


@dataclass
class MujocoCameraConfig:
    """A fixed camera at ``eye`` looking at ``target`` (world metres), ``fov`` degrees vertical, ``width`` x
    ``height`` pixels."""

    eye: tuple[float, float, float] = (0.78, 0.0, 0.95)
    target: tuple[float, float, float] = (0.5, 0.02, 0.4)
    fov: float = 58.0
    width: int = 256
    height: int = 256


@dataclass
class MujocoPickPlaceConfig(PickPlaceSettings):
    """Everything the MuJoCo demo needs (mirrors ``configs/robot/mujoco_pick_place.yaml``): the shared settings
    (:class:`~tvrecon.robot.pick_place_common.PickPlaceSettings`) and these.

    squeeze_time, settle_time, release_time: seconds. frame_every: physics steps per logged frame (each logged frame
    reads the pads).
    """

    squeeze_time: float = 0.4
    settle_time: float = 0.16
    release_time: float = 0.3
    frame_every: int = 10
    render_eye: tuple[float, float, float] = (0.92, 0.0, 0.78)
    render_target: tuple[float, float, float] = (0.5, 0.0, 0.5)
    out_dir: str = "outputs/robot_mujoco"
    scene: MujocoSceneConfig = field(default_factory=MujocoSceneConfig)
    camera: MujocoCameraConfig = field(default_factory=MujocoCameraConfig)

    @classmethod
    def from_dict(cls, d: dict) -> MujocoPickPlaceConfig:
        """Build from a plain (Hydra/OmegaConf container) dict; nested dicts fill the nested dataclasses."""
        return coerce_config(cls, d, "mujoco_pick_place")


@dataclass
class MujocoPickPlaceResult:
    """Outcome of a run: success, message, phase reached, placement error (m), outputs, timings and the log."""

    success: bool
    message: str
    phase_reached: str
    plan: GraspPlan | None
    placement_error: float
    log: dict[str, np.ndarray]
    log_path: Path | None
    gif_path: Path | None
    mp4_path: Path | None
    strip_path: Path | None
    wall_time: float
    num_presses: int
    rendered: bool
