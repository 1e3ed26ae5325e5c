"""Robot scenes with EIP tactile sensors (pybullet): a Panda pick-and-place demo and a reusable TactileFinger.

Needs the optional ``robot`` extra (``pip install tvrecon[robot]`` for pybullet). Entry point::

    python -m tvrecon.robot.pick_place object=can

MuJoCo (the optional ``mujoco`` extra, imported only from its own modules):
``tvrecon.robot.mujoco_sensor.TactileSensor`` is the pad on any MuJoCo geom or body,
``python -m tvrecon.robot.mujoco_pick_place object=can`` the demo. The engine-independent pad both engines share is
``tvrecon.robot.pad``.
"""

from tvrecon.robot.finger import TactileFinger
from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pad_reading import FingerReading
from tvrecon.robot.perception import CameraConfig, GraspPlan, RGBDCamera, plan_top_grasp
from tvrecon.robot.scene import Scene, SceneConfig

__all__ = [
    "CameraConfig",
    "FingerReading",
    "GraspPlan",
    "PadConfig",
    "RGBDCamera",
    "Scene",
    "SceneConfig",
    "TactileFinger",
    "plan_top_grasp",
]
