"""The configuration of the pybullet pick-and-place demo (:mod:`tvrecon.robot.pybullet.pick_place`), read by its arm
controller too (:mod:`tvrecon.robot.pybullet.controller`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import trimesh

from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pybullet.camera import CameraConfig
from tvrecon.robot.pybullet.scene import SceneConfig
from tvrecon.utils.config_utils import coerce_config

__all__ = ["PickPlaceConfig"]


@dataclass
class PickPlaceConfig:
    """Everything the demo needs (mirrors ``configs/robot/pick_place.yaml``).

    object: a procedural class name (``tvrecon.data.shapes``) or a path to a mesh file trimesh can load.
    place_xy: (2,) where the object is put down. lift_height / carry_height: metres above the grasp height.
    speed: Cartesian hand speed, m/s. grip_force: finger motor force, N. frame_every: simulation steps per logged
    frame. render_size: (W, H) of the scene frames. out_dir: where the GIF, strip and log go.
    """

    object: str = "can"
    seed: int = 0
    mesh: trimesh.Trimesh | None = None  # a mesh given directly through the Python API (overrides ``object``)
    place_xy: tuple[float, float] = (0.5, 0.15)
    approach_height: float = 0.10
    lift_height: float = 0.12
    speed: float = 0.2
    close_speed: float = 0.05
    grip_force: float = 40.0
    squeeze_steps: int = 90
    settle_steps: int = 40
    frame_every: int = 8
    contact_force: float = 6.0
    render: bool = True
    render_size: tuple[int, int] = (256, 192)
    render_eye: tuple[float, float, float] = (0.98, 0.0, 0.86)
    render_target: tuple[float, float, float] = (0.47, 0.0, 0.69)
    out_dir: str = "outputs/robot"
    write_gif: bool = True
    write_mp4: bool = True  # needs imageio-ffmpeg ([robot] extra); skipped with a warning when missing
    write_strip: bool = True
    progress: bool = True
    torch_threads: int | None = 1  # small EIP presses run fastest single-threaded; None keeps torch's setting
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    pad: PadConfig = field(default_factory=PadConfig)

    @classmethod
    def from_dict(cls, d: dict) -> PickPlaceConfig:
        """Build from a plain (Hydra/OmegaConf container) dict; nested dicts fill the nested dataclasses."""
        return coerce_config(cls, d, "pick_place")
