"""The arm and gripper of the pick-and-place demo: Cartesian moves through IK, the gripper motor, the per-frame log.

:class:`ArmController` drives the Panda of a :class:`~tvrecon.robot.pybullet.scene.Scene` through pybullet (joint
position control of the IK solution along straight lines of the grasp point) and records, every ``frame_every``
simulation steps, the object and hand poses, both fingers' tactile readings and a rendered frame.
:mod:`tvrecon.robot.pybullet.pick_place` sequences the task's phases with it.
"""

from __future__ import annotations

import numpy as np
import pybullet as p
from tqdm.auto import tqdm

from tvrecon.robot.pad_reading import FingerReading, reading_record
from tvrecon.robot.pick_place_common import PHASES
from tvrecon.robot.pybullet.finger import TactileFinger, sense_fingers
from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig
from tvrecon.robot.pybullet.scene import (
    PANDA_ARM_JOINTS,
    PANDA_FINGER_JOINTS,
    PANDA_GRASP_LINK,
    PANDA_MAX_OPENING,
    PANDA_REST,
    Scene,
)

__all__ = ["ArmController", "hand_orientation"]

_ARM_FORCES = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
_LOWER = [-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671, 0.0, 0.0]
_UPPER = [2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671, 0.04, 0.04]
_RANGES = [u - lo for u, lo in zip(_UPPER, _LOWER)]
_REST = list(PANDA_REST) + [0.02, 0.02]


class ArmController:
    """Cartesian straight-line moves through IK + joint position control, with logging at every phase."""

    def __init__(self, scene: Scene, cfg: PickPlaceConfig, fingers: tuple[TactileFinger, TactileFinger]) -> None:
        self.scene, self.cfg, self.fingers = scene, cfg, fingers
        self.cid, self.robot = scene.client, scene.robot
        self.step_count = 0
        self.records: list[dict] = []
        self.phase = "approach"
        self.phase_fresh = True
        self.grip_target = PANDA_MAX_OPENING / 2
        self.grip_force = cfg.grip_force
        self.grip_speed = cfg.close_speed
        view = p.computeViewMatrix(cfg.render_eye, cfg.render_target, (0, 0, 1), physicsClientId=self.cid)
        W, H = cfg.render_size
        proj = p.computeProjectionMatrixFOV(45.0, W / H, 0.05, 4.0, physicsClientId=self.cid)
        self.render_mats = (view, proj)
        self.bar = tqdm(total=None, desc="pick-place", unit="step", disable=not cfg.progress)

    # ------------------------------------------------------------------ low level
    def ik(self, pos: np.ndarray, orn: np.ndarray) -> list[float]:
        q = p.calculateInverseKinematics(
            self.robot,
            PANDA_GRASP_LINK,
            list(pos),
            list(orn),
            lowerLimits=_LOWER,
            upperLimits=_UPPER,
            jointRanges=_RANGES,
            restPoses=_REST,
            maxNumIterations=60,
            residualThreshold=1e-5,
            physicsClientId=self.cid,
        )
        return list(q[:7])

    def command_arm(self, q: list[float]) -> None:
        p.setJointMotorControlArray(
            self.robot,
            list(PANDA_ARM_JOINTS),
            p.POSITION_CONTROL,
            targetPositions=q,
            forces=list(_ARM_FORCES),
            physicsClientId=self.cid,
        )

    def command_gripper(self) -> None:
        for j in PANDA_FINGER_JOINTS:
            p.setJointMotorControl2(
                self.robot,
                j,
                p.POSITION_CONTROL,
                targetPosition=self.grip_target,
                force=self.grip_force,
                maxVelocity=self.grip_speed,
                physicsClientId=self.cid,
            )

    def step(self) -> None:
        self.command_gripper()
        p.stepSimulation(physicsClientId=self.cid)
        self.step_count += 1
        self.bar.update(1)
        if self.step_count % self.cfg.frame_every == 0:
            self.record()

    def set_phase(self, name: str) -> None:
        self.phase = name
        self.phase_fresh = True
        self.bar.set_postfix_str(name)

    # ------------------------------------------------------------------ logging
    def render(self) -> np.ndarray:
        W, H = self.cfg.render_size
        if not self.cfg.render:
            return np.zeros((H, W, 3), np.uint8)
        img = p.getCameraImage(W, H, *self.render_mats, renderer=p.ER_TINY_RENDERER, physicsClientId=self.cid)[2]
        return np.asarray(img, dtype=np.uint8).reshape(H, W, 4)[..., :3].copy()

    def record(self) -> None:
        readings: list[FingerReading] = sense_fingers(self.fingers, refresh=self.phase_fresh)
        self.phase_fresh = False
        obj_pos, obj_orn = self.scene.object_pose()
        ee_pos, ee_orn = self.scene.link_pose(PANDA_GRASP_LINK)
        self.records.append(
            {
                "step": self.step_count,
                "time": self.step_count * self.scene.cfg.time_step,
                "phase": PHASES.index(self.phase),
                "object_pos": obj_pos,
                "object_quat": obj_orn,
                "ee_pos": ee_pos,
                "ee_quat": ee_orn,
                "finger_q": self.scene.finger_positions(),
                **reading_record(readings),
                "frame": self.render(),
            }
        )

    # ------------------------------------------------------------------ motions
    def move_to(self, target: np.ndarray, orn: np.ndarray, speed: float | None = None) -> None:
        """Straight line of the grasp point from where it is to ``target`` at ``speed`` m/s, then settle."""
        start, _ = self.scene.link_pose(PANDA_GRASP_LINK)
        dist = float(np.linalg.norm(target - start))
        n = max(2, int(np.ceil(dist / ((speed or self.cfg.speed) * self.scene.cfg.time_step))))
        for k in range(1, n + 1):
            s = k / n
            s = s * s * (3 - 2 * s)  # smoothstep: zero velocity at both ends
            self.command_arm(self.ik(start + s * (target - start), orn))
            self.step()
        q = self.ik(target, orn)
        for _ in range(self.cfg.settle_steps):
            self.command_arm(q)
            self.step()

    def hold(self, steps: int, q: list[float] | None = None) -> None:
        for _ in range(steps):
            if q is not None:
                self.command_arm(q)
            self.step()

    def close_until_contact(self, max_steps: int) -> bool:
        """Close both fingers slowly until both touch the object (or they are shut)."""
        self.grip_target = 0.0
        for _ in range(max_steps):
            self.step()
            if all(len(f.contacts()) > 0 for f in self.fingers):
                return True
            if self.scene.finger_positions().max() < 1e-3:
                return False
        return all(len(f.contacts()) > 0 for f in self.fingers)


def hand_orientation(closing_axis: np.ndarray) -> np.ndarray:
    """xyzw quaternion of a hand pointing down (z = -world z) with its finger axis (y) along ``closing_axis``."""
    y = np.asarray(closing_axis, dtype=np.float64)
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()
