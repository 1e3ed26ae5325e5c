"""The MuJoCo room of the robot scenes (needs the ``mujoco`` extra): the EIP pad on any MuJoCo geom or body
(:class:`tvrecon.robot.mujoco.sensor.TactileSensor`), the floating-gripper scene, its camera, and the pick-and-place
demo (``python -m tvrecon.robot.mujoco.pick_place``). Nothing here imports pybullet."""
