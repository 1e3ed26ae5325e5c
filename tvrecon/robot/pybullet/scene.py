"""The pybullet world of the pick-and-place demo: floor, table, Franka Panda and an object built from a mesh.

Everything runs in a headless ``pybullet.DIRECT`` client owned by :class:`Scene`. Units are SI (metres, kg, N).
The object is a pybullet body whose base frame is the mesh's own frame after
:func:`~tvrecon.robot.pick_place_common.prepare_object_mesh` (scaled to a real size, centred on its centre of mass),
so ``mesh.apply_transform(scene.object_transform())`` is the object's surface in world coordinates at the current
simulation step.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as p
import pybullet_data
import trimesh

from tvrecon.robot.pick_place_common import prepare_object_mesh

__all__ = [
    "PANDA_ARM_JOINTS",
    "PANDA_FINGER_JOINTS",
    "PANDA_FINGER_LINKS",
    "PANDA_GRASP_LINK",
    "PANDA_MAX_OPENING",
    "SceneConfig",
    "Scene",
    "collision_shape_for_mesh",
]

PANDA_ARM_JOINTS = (0, 1, 2, 3, 4, 5, 6)
PANDA_FINGER_JOINTS = (9, 10)  # panda_finger_joint1 (left, +y of the hand), panda_finger_joint2 (right, -y)
PANDA_FINGER_LINKS = (9, 10)  # the link index of a pybullet joint is the index of its child link
PANDA_GRASP_LINK = 11  # panda_grasptarget: between the fingertips, 0.105 m below the hand frame
PANDA_MAX_OPENING = 0.08  # each finger travels 0..0.04 m
PANDA_REST = (0.0, -0.4, 0.0, -2.3, 0.0, 1.9, 0.785)  # a comfortable "ready" pose above the table


@dataclass
class SceneConfig:
    """Geometry and physics of the world.

    table_xy: (2,) centre of pybullet_data's table (1.5 m x 1 m, top at ``table_height``).
    robot_xy: (2,) where the Panda's base stands on the table top.
    object_xy: (2,) where the object is put down (its lowest point rests on the table).
    object_size: longest side of the object's bounding box after scaling, metres.
    object_density: kg / m^3 used with the mesh volume for the object's mass (clamped to ``mass_range``).
    friction: lateral friction coefficient of the object (the Panda fingers have 1.0 in the URDF).
    """

    table_xy: tuple[float, float] = (0.55, 0.0)
    table_height: float = 0.625
    robot_xy: tuple[float, float] = (0.0, 0.0)
    object_xy: tuple[float, float] = (0.5, -0.15)
    object_yaw: float = 0.3
    object_size: float = 0.065
    object_density: float = 400.0
    mass_range: tuple[float, float] = (0.02, 0.6)
    friction: float = 1.0
    spinning_friction: float = 0.002
    rolling_friction: float = 0.0001
    object_color: tuple[float, float, float, float] = (0.85, 0.25, 0.2, 1.0)
    time_step: float = 1.0 / 240.0
    solver_iterations: int = 150
    convex_tolerance: float = 0.85  # volume / hull volume above this -> use the convex hull, else V-HACD
    vhacd_resolution: int = 200_000
    cache_dir: str | None = None  # where V-HACD decompositions are kept (None -> a temp dir)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Send C-level stdout to /dev/null for the duration (pybullet's V-HACD is chatty)."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def collision_shape_for_mesh(
    mesh: trimesh.Trimesh,
    client: int,
    convex_tolerance: float = 0.92,
    cache_dir: str | Path | None = None,
    resolution: int = 200_000,
) -> tuple[int, str]:
    """Create a pybullet collision shape for a mesh in its body frame.

    Convex-ish meshes (volume / convex-hull volume >= ``convex_tolerance``) use pybullet's convex hull of the
    vertices; others are decomposed with ``pybullet.vhacd`` into convex parts loaded as one compound shape.

    Returns:
        (shape id, "hull" | "vhacd")
    """
    hull_ratio = 1.0
    if mesh.is_volume:
        hull_ratio = float(mesh.volume / max(mesh.convex_hull.volume, 1e-12))
    if hull_ratio >= convex_tolerance:
        verts = np.asarray(mesh.convex_hull.vertices, dtype=np.float64)
        sid = p.createCollisionShape(p.GEOM_MESH, vertices=verts.tolist(), physicsClientId=client)
        return sid, "hull"
    root = Path(cache_dir) if cache_dir is not None else Path(tempfile.gettempdir()) / "tvrecon_vhacd"
    root.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha1(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    key = f"{digest.hexdigest()[:16]}_{resolution}"
    src, dst = root / f"{key}_in.obj", root / f"{key}_vhacd.obj"
    if not dst.exists():
        tmp_src = src.with_suffix(f".{os.getpid()}.obj")
        mesh.export(tmp_src)
        os.replace(tmp_src, src)
        tmp_dst = root / f"{key}_vhacd.{os.getpid()}.obj"
        with _quiet_stdout():  # V-HACD prints its whole parameter sheet and progress to C stdout
            p.vhacd(str(src), str(tmp_dst), str(root / f"{key}_log.txt"), resolution=resolution, physicsClientId=client)
        os.replace(tmp_dst, dst)
    sid = p.createCollisionShape(p.GEOM_MESH, fileName=str(dst), physicsClientId=client)
    return sid, "vhacd"


class Scene:
    """A headless pybullet world with a table, a Franka Panda (fixed base on the table) and one object.

    Args:
        mesh: the object's mesh in any frame and scale (it is scaled to ``cfg.object_size`` and re-centred).
        cfg: scene geometry and physics.
    """

    def __init__(self, mesh: trimesh.Trimesh, cfg: SceneConfig | None = None) -> None:
        self.cfg = cfg or SceneConfig()
        c = self.cfg
        self.client = p.connect(p.DIRECT)
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self.client)
        p.setGravity(0, 0, -9.81, physicsClientId=self.client)
        p.setPhysicsEngineParameter(
            fixedTimeStep=c.time_step, numSolverIterations=c.solver_iterations, physicsClientId=self.client
        )
        self.plane = p.loadURDF("plane.urdf", physicsClientId=self.client)
        self.table = p.loadURDF(
            "table/table.urdf",
            basePosition=[c.table_xy[0], c.table_xy[1], 0.0],
            useFixedBase=True,
            physicsClientId=self.client,
        )
        self.robot = p.loadURDF(
            "franka_panda/panda.urdf",
            basePosition=[c.robot_xy[0], c.robot_xy[1], c.table_height],
            useFixedBase=True,
            flags=p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT,
            physicsClientId=self.client,
        )
        for j, q in zip(PANDA_ARM_JOINTS, PANDA_REST):
            p.resetJointState(self.robot, j, q, physicsClientId=self.client)
        for j in PANDA_FINGER_JOINTS:
            p.resetJointState(self.robot, j, PANDA_MAX_OPENING / 2, physicsClientId=self.client)
        # the real Panda's fingers are mechanically coupled: a gear constraint keeps them symmetric about the hand
        gear = p.createConstraint(
            self.robot,
            PANDA_FINGER_JOINTS[0],
            self.robot,
            PANDA_FINGER_JOINTS[1],
            jointType=p.JOINT_GEAR,
            jointAxis=[1, 0, 0],
            parentFramePosition=[0, 0, 0],
            childFramePosition=[0, 0, 0],
            physicsClientId=self.client,
        )
        p.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50, physicsClientId=self.client)

        self.mesh = prepare_object_mesh(mesh, c.object_size)  # body frame, metres
        self.collision_kind = "none"
        self.object = self._add_object(self.mesh)
        self.settle(120)

    # ------------------------------------------------------------------ object
    def _add_object(self, mesh: trimesh.Trimesh) -> int:
        c = self.cfg
        col, self.collision_kind = collision_shape_for_mesh(
            mesh, self.client, c.convex_tolerance, c.cache_dir, c.vhacd_resolution
        )
        vis = p.createVisualShape(
            p.GEOM_MESH,
            vertices=np.asarray(mesh.vertices).tolist(),
            indices=np.asarray(mesh.faces).ravel().tolist(),
            rgbaColor=list(c.object_color),
            physicsClientId=self.client,
        )
        volume = float(mesh.volume) if mesh.is_volume else float(mesh.convex_hull.volume)
        self.mass = float(np.clip(volume * c.object_density, *c.mass_range))
        orn = p.getQuaternionFromEuler([0.0, 0.0, c.object_yaw])
        rot = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        z_min = float((np.asarray(mesh.vertices) @ rot.T)[:, 2].min())
        pos = [c.object_xy[0], c.object_xy[1], c.table_height - z_min + 1e-4]
        body = p.createMultiBody(
            baseMass=self.mass,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=pos,
            baseOrientation=orn,
            physicsClientId=self.client,
        )
        p.changeDynamics(
            body,
            -1,
            lateralFriction=c.friction,
            spinningFriction=c.spinning_friction,
            rollingFriction=c.rolling_friction,
            restitution=0.0,
            physicsClientId=self.client,
        )
        return body

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Return ((3,) position, (4,) xyzw quaternion) float64 of the object's body frame in world."""
        pos, orn = p.getBasePositionAndOrientation(self.object, physicsClientId=self.client)
        return np.asarray(pos, dtype=np.float64), np.asarray(orn, dtype=np.float64)

    def object_transform(self) -> np.ndarray:
        """Return the (4,4) float64 body-to-world transform of the object."""
        pos, orn = self.object_pose()
        T = np.eye(4)
        T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def object_mesh_world(self) -> trimesh.Trimesh:
        """The object's surface in world coordinates at the current step (a new trimesh)."""
        return self.mesh.copy().apply_transform(self.object_transform())

    # ------------------------------------------------------------------ robot
    def link_pose(self, link: int) -> tuple[np.ndarray, np.ndarray]:
        """Return ((3,), (4,) xyzw) world pose of a Panda link frame."""
        st = p.getLinkState(self.robot, link, computeForwardKinematics=True, physicsClientId=self.client)
        return np.asarray(st[4], dtype=np.float64), np.asarray(st[5], dtype=np.float64)

    def finger_positions(self) -> np.ndarray:
        """Return the (2,) float64 finger joint positions (metres each finger is open)."""
        return np.array([p.getJointState(self.robot, j, physicsClientId=self.client)[0] for j in PANDA_FINGER_JOINTS])

    def settle(self, steps: int) -> None:
        """Step the world ``steps`` times with the current motor targets."""
        for _ in range(steps):
            p.stepSimulation(physicsClientId=self.client)

    def close(self) -> None:
        """Disconnect the pybullet client (idempotent)."""
        if self.client is not None and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = None

    def __enter__(self) -> Scene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
