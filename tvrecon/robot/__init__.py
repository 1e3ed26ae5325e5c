"""Robot scenes with EIP tactile sensors: the pad core both physics engines share, and one room per engine.

The core (this package's modules) imports no engine: the pad on a robot link (:mod:`tvrecon.robot.pad_sensor`,
:mod:`tvrecon.robot.pad_config`, :mod:`tvrecon.robot.pad_reading`), the grasp planned from a point cloud, what both
pick-and-place demos share and their figures. Each engine lives in its own room and is imported only there:

- :mod:`tvrecon.robot.pybullet` (the optional ``robot`` extra, ``pip install tvrecon[robot]``): ``TactileFinger``
  on any pybullet link and a Panda pick-and-place, ``python -m tvrecon.robot.pybullet.pick_place object=can``;
- :mod:`tvrecon.robot.mujoco` (the optional ``mujoco`` extra): ``TactileSensor`` on any MuJoCo geom or body and a
  floating-gripper pick-and-place, ``python -m tvrecon.robot.mujoco.pick_place object=can``.
"""

from tvrecon.robot.grasp import GraspPlan, plan_top_grasp
from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pad_reading import FingerReading

__all__ = ["FingerReading", "GraspPlan", "PadConfig", "plan_top_grasp"]
