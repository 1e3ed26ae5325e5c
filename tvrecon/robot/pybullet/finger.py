"""TactileFinger: an EIP sensor pad carried by any pybullet body link, pressed by that link's real contacts.

At each :meth:`TactileFinger.sense` the link's pybullet contacts with registered objects (getContactPoints:
position on the object, normal, penetration, normal force) set up an EIP press of the pad against the object's own
mesh at its current pose (body frame -> world). The engine-independent part (which press to run, caching, the
batched solver call, the pad-frame image, force field and contact patch) is :class:`tvrecon.robot.pad_sensor.PadSensor`,
shared with the MuJoCo sensor (``tvrecon.robot.mujoco.sensor``); this module is the pybullet side.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet as p

from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pad_reading import ContactPoint, FingerReading
from tvrecon.robot.pad_sensor import PadSensor, sense_pads

__all__ = ["TactileFinger", "sense_fingers"]


class TactileFinger(PadSensor):
    """An EIP pad on a pybullet link.

    Args:
        body: pybullet body unique id carrying the pad (e.g. the robot).
        link: link index of the finger (-1 = base).
        normal_axis: (3,) pad press direction in the link frame (the finger's closing direction).
        up_axis: (3,) pad "up" axis in the link frame (image rows), e.g. along the finger towards its tip.
        pad_center: (3,) centre of the pad's contact face in the link frame; the press is then centred on the pad
            (the contact plane point in front of it), so the image shows where on the pad the object touches.
            None centres the press on the force-weighted contact point instead.
        pad: pad geometry and caching thresholds.
        simulator: a ``tvrecon.sim.press.simulator.EIPSimulator``; None builds one from ``pad``.
        client: pybullet physics client id.
        name: label used in logs.
    """

    def __init__(
        self,
        body: int,
        link: int,
        normal_axis: Sequence[float],
        up_axis: Sequence[float] = (0.0, 0.0, 1.0),
        pad_center: Sequence[float] | None = None,
        pad: PadConfig | None = None,
        simulator: object | None = None,
        client: int = 0,
        name: str = "finger",
    ) -> None:
        super().__init__(normal_axis, up_axis, pad_center, pad, simulator, name)
        self.body, self.link, self.client = int(body), int(link), int(client)

    # ------------------------------------------------------------------ engine side
    def link_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) world position, (3,3) world rotation) float64 of the finger link frame."""
        if self.link < 0:
            pos, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        else:
            st = p.getLinkState(self.body, self.link, computeForwardKinematics=True, physicsClientId=self.client)
            pos, orn = st[4], st[5]
        return np.asarray(pos, dtype=np.float64), np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)

    def object_transform(self, key: int) -> np.ndarray:
        """(4,4) float64 world transform of body ``key``'s base frame."""
        pos, orn = p.getBasePositionAndOrientation(key, physicsClientId=self.client)
        T = np.eye(4)
        T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def contacts(self) -> list[tuple]:
        """pybullet contact points between this link and registered objects (touching: distance <= 0)."""
        out = []
        for body in self.objects:
            pts = p.getContactPoints(bodyA=self.body, bodyB=body, linkIndexA=self.link, physicsClientId=self.client)
            out.extend(c for c in pts if c[8] <= 1e-5)
        return out

    def contact_points(self) -> list[ContactPoint]:
        """:meth:`contacts` as engine-independent :class:`~tvrecon.robot.pad_reading.ContactPoint` (normal on B: object
        -> finger)."""
        return [
            ContactPoint(int(c[2]), np.asarray(c[6], np.float64), np.asarray(c[7], np.float64), -float(c[8]), c[9])
            for c in self.contacts()
        ]


def sense_fingers(fingers: Sequence[TactileFinger], refresh: bool = False) -> list[FingerReading]:
    """Read several fingers at the current step, their presses batched (:func:`tvrecon.robot.pad_sensor.sense_pads`)."""
    return sense_pads(fingers, refresh=refresh)
