"""The pybullet room of the robot scenes (needs the ``robot`` extra): the EIP pad on any pybullet link
(:class:`TactileFinger`), the Panda scene, its camera and arm, and the pick-and-place demo
(``python -m tvrecon.robot.pybullet.pick_place``)."""

from tvrecon.robot.pybullet.camera import CameraConfig, RGBDCamera
from tvrecon.robot.pybullet.finger import TactileFinger
from tvrecon.robot.pybullet.scene import Scene, SceneConfig

__all__ = ["CameraConfig", "RGBDCamera", "Scene", "SceneConfig", "TactileFinger"]
