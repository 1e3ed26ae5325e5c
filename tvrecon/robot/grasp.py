"""A grasp planned from the object's segmented point cloud, the same for both engines.

No ground-truth pose is used: each engine's camera (:mod:`tvrecon.robot.pybullet.camera`,
:mod:`tvrecon.robot.mujoco.camera`) renders depth and a segmentation image, the object's pixels are back-projected to
a world point cloud, and the grasp comes from that cloud's principal axes (centre of its bounding rectangle, closing
direction across the narrow horizontal width, height from its top).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvrecon.utils.shape_check import check_shape

__all__ = ["GraspPlan", "plan_top_grasp"]


@dataclass
class GraspPlan:
    """A top-down parallel-jaw grasp planned from a segmented point cloud (world frame, metres).

    position: (3,) where the gripper's grasp target (between the fingertips) goes.
    closing_axis: (3,) unit horizontal direction the fingers move along (left finger moves along -axis).
    yaw: rotation of the hand about world z, radians.
    width: object extent across ``closing_axis``; length: along the major axis; top_z: highest point.
    centroid: (3,) mean of the visible points; n_points: how many object pixels the camera saw.
    feasible: False when the gripper cannot hold the object; reason: human-readable explanation.
    """

    position: np.ndarray
    closing_axis: np.ndarray
    yaw: float
    width: float
    length: float
    top_z: float
    centroid: np.ndarray
    n_points: int
    feasible: bool
    reason: str


def plan_top_grasp(
    points: np.ndarray,
    table_z: float,
    max_opening: float = 0.08,
    clearance: float = 0.008,
    min_width: float = 0.01,
    grasp_depth: float = 0.025,
    tip_clearance: float = 0.012,
    min_points: int = 30,
) -> GraspPlan:
    """Plan a top-down grasp across the narrow horizontal width of an object's visible point cloud.

    The horizontal principal axes of the points give the object's major and minor directions; the centre of the
    points' bounding rectangle in that frame (1st-99th percentiles) is the grasp centre (robust to the camera
    seeing one side more than the other). The grasp goes ``grasp_depth`` below the top, but never lower than
    ``tip_clearance`` above the table.

    Args:
        points: (N,3) float world points of the object (N >= ``min_points``).
        table_z: height of the supporting surface, metres.
        max_opening: the gripper's full opening; the object must fit with ``clearance`` on each side.

    Returns:
        A :class:`GraspPlan`; ``feasible`` False (with ``reason``) if the object is too wide, too small or unseen.
    """
    pts = np.asarray(points, dtype=np.float64)
    check_shape(pts, "(N, 3)", "points")
    nan3 = np.full(3, np.nan)
    if len(pts) < min_points:
        return GraspPlan(
            nan3,
            nan3,
            0.0,
            0.0,
            0.0,
            float(table_z),
            nan3,
            len(pts),
            False,
            f"object not found by the camera: {len(pts)} segmented points < {min_points} (outside the camera's view, "
            "hidden, or too small to see)",
        )
    centroid = pts.mean(axis=0)
    xy = pts[:, :2] - centroid[:2]
    cov = xy.T @ xy / len(xy)
    evals, evecs = np.linalg.eigh(cov)  # ascending
    minor, major = evecs[:, 0], evecs[:, 1]
    a = xy @ major
    b = xy @ minor
    lo_a, hi_a = np.percentile(a, [1, 99])
    lo_b, hi_b = np.percentile(b, [1, 99])
    length, width = float(hi_a - lo_a), float(hi_b - lo_b)
    centre_xy = centroid[:2] + major * (lo_a + hi_a) / 2 + minor * (lo_b + hi_b) / 2
    top_z = float(np.percentile(pts[:, 2], 99.5))
    height = top_z - table_z
    grasp_z = max(top_z - grasp_depth, table_z + tip_clearance)
    # the hand's y axis (finger travel) is the closing axis; pick the sign that keeps the wrist yaw near zero
    closing = np.array([minor[0], minor[1], 0.0])
    if closing[1] > 0:
        closing = -closing
    yaw = float(np.arctan2(closing[0], -closing[1]))
    feasible, reason = True, "ok"
    if width + 2 * clearance > max_opening:
        feasible = False
        reason = (
            f"object too wide to grasp: {width * 100:.1f} cm across its narrowest horizontal axis, the gripper "
            f"opens {max_opening * 100:.1f} cm (needs {clearance * 100:.1f} cm clearance per side)"
        )
    elif width < min_width:
        feasible = False
        reason = f"object too small to grasp: {width * 100:.1f} cm wide < {min_width * 100:.1f} cm"
    elif height < tip_clearance + 0.005:
        feasible = False
        reason = f"object too flat to grasp: {height * 100:.1f} cm tall, fingertips need {tip_clearance * 100:.1f} cm"
    return GraspPlan(
        position=np.array([centre_xy[0], centre_xy[1], grasp_z]),
        closing_axis=closing,
        yaw=yaw,
        width=width,
        length=length,
        top_z=top_z,
        centroid=centroid,
        n_points=len(pts),
        feasible=feasible,
        reason=reason,
    )
