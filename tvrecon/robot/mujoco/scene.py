"""The MuJoCo world of the MuJoCo pick-and-place: floor, table, a floating parallel gripper and one object mesh.

The gripper is written here in MJCF (no registry package ships a Panda MJCF under a license we could vendor): a hand
on three slide joints and a yaw hinge driven by position actuators (gravity compensated), two fingers on slide joints
coupled by an equality (they close symmetrically, like the real Panda's gear), each driven by a force motor (the
grip force in newtons). Each finger's inner box is its tactile pad geom (``left_pad`` / ``right_pad``).

The object is a free body whose single mesh geom is the prepared object mesh (``prepare_object_mesh``: scaled to a
real size, centred on its centre of mass); MuJoCo collides with its convex hull, the tactile pads press the mesh
itself. Rendering uses MuJoCo's offscreen renderer (``MUJOCO_GL=egl`` headless; set here when unset).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless offscreen rendering; read when mujoco is imported

from dataclasses import dataclass  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from tvrecon.robot.pick_place_common import prepare_object_mesh  # noqa: E402

__all__ = [
    "FINGER_HALF",
    "MAX_OPENING",
    "MujocoScene",
    "MujocoSceneConfig",
    "gripper_xml",
    "look_at_xyaxes",
]

MAX_OPENING = 0.09  # metres between the pads when open; each finger travels 0..MAX_OPENING / 2
FINGER_HALF = (0.011, 0.005, 0.016)  # half sizes of a pad box (x across, y thickness, z along the finger)
KNUCKLE = 0.03  # metres of finger between the pad's top and the palm
PAD_BELOW_HAND = FINGER_HALF[2] + KNUCKLE + 0.01  # the pads' centre is this far below the hand frame


@dataclass
class MujocoSceneConfig:
    """Geometry and physics of the MuJoCo world (SI units).

    table_height: top of the table. object_xy / object_yaw: where the object is put down. object_size: its longest
    side. object_density: kg / m^3 on the mesh volume, mass clamped to ``mass_range``. friction: sliding friction of
    the object (the pads have ``pad_friction``). time_step: physics step. hand_kp: N/m of the hand's position servo.
    max_grip_force: N per finger.
    """

    table_height: float = 0.4
    table_xy: tuple[float, float] = (0.5, 0.0)
    object_xy: tuple[float, float] = (0.5, -0.15)
    object_yaw: float = 0.3
    object_size: float = 0.065
    object_density: float = 400.0
    mass_range: tuple[float, float] = (0.02, 0.6)
    friction: float = 1.0
    pad_friction: float = 1.5
    object_color: tuple[float, float, float, float] = (0.85, 0.25, 0.2, 1.0)
    time_step: float = 0.002
    hand_kp: float = 5000.0
    hand_start: tuple[float, float, float] = (0.5, 0.0, 0.65)
    max_grip_force: float = 100.0


def look_at_xyaxes(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """(6,) MJCF ``xyaxes`` of a camera at ``eye`` looking at ``target`` (MuJoCo cameras look along their -z)."""
    z = np.asarray(eye, np.float64) - np.asarray(target, np.float64)
    if np.linalg.norm(z) < 1e-9:
        raise ValueError("camera eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, np.float64), z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([1.0, 0.0, 0.0]), z)
    x /= np.linalg.norm(x)
    return np.concatenate([x, np.cross(z, x)])


def _fmt(a: object) -> str:
    return " ".join(f"{float(v):.6g}" for v in np.ravel(a))


def gripper_xml(mesh: trimesh.Trimesh, cfg: MujocoSceneConfig, cameras: dict[str, tuple] | None = None) -> str:
    """The scene's MJCF: floor, table, gripper, the object mesh (vertices (V,3), faces (F,3) inline) and cameras.

    Args:
        mesh: the object's surface in its body frame (metres, centre of mass at the origin).
        cameras: name -> (eye (3,), target (3,), fovy degrees).
    """
    c = cfg
    volume = float(mesh.volume) if mesh.is_volume else float(mesh.convex_hull.volume)
    mass = float(np.clip(volume * c.object_density, *c.mass_range))
    rot = trimesh.transformations.rotation_matrix(c.object_yaw, [0, 0, 1])[:3, :3]
    z0 = c.table_height - float((np.asarray(mesh.vertices) @ rot.T)[:, 2].min()) + 1e-4
    fx, fy, fz = FINGER_HALF
    open_y = MAX_OPENING / 2 + fy  # finger centre when open
    knuckle_z = fz + KNUCKLE / 2
    cams = "".join(
        f'<camera name="{n}" pos="{_fmt(e)}" xyaxes="{_fmt(look_at_xyaxes(e, t))}" fovy="{fov}"/>'
        for n, (e, t, fov) in (cameras or {}).items()
    )
    finger = (
        '<body name="{n}" pos="0 {y:.6g} {z:.6g}" gravcomp="1">'
        '<joint name="{n}" type="slide" axis="0 {s} 0" range="0 {r:.6g}" damping="20" armature="0.01"/>'
        '<geom name="{n}_pad" type="box" size="{fx} {fy} {fz}" mass="0.05" rgba="0.15 0.15 0.15 1" condim="4" '
        'friction="{mu} 0.02 0.0001" solref="0.01 1"/>'
        '<geom name="{n}_knuckle" type="box" pos="0 {ky:.6g} {kz:.6g}" size="{fx} {fy} {kh:.6g}" mass="0.02" '
        'contype="0" conaffinity="0" rgba="0.6 0.6 0.65 1"/>'
        "</body>"
    )
    fingers = "".join(
        finger.format(
            n=n,
            y=sgn * open_y,
            z=-PAD_BELOW_HAND,
            s=-sgn,
            r=MAX_OPENING / 2,
            fx=fx,
            fy=fy,
            fz=fz,
            mu=c.pad_friction,
            ky=sgn * 0.002,
            kz=knuckle_z,
            kh=KNUCKLE / 2,
        )
        for n, sgn in (("left", 1), ("right", -1))
    )
    kv = 2.0 * np.sqrt(c.hand_kp * 0.8)  # about critical damping of the hand's mass
    return f"""
<mujoco model="tvrecon_mujoco_pick_place">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{c.time_step}" cone="elliptic" impratio="10" integrator="implicitfast"/>
  <visual><global offwidth="640" offheight="480"/><quality shadowsize="1024"/></visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1=".85 .85 .85" rgb2=".75 .75 .75" width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8"/>
    <mesh name="object" vertex="{_fmt(mesh.vertices)}" face="{" ".join(str(int(i)) for i in np.ravel(mesh.faces))}"
          inertia="convex"/>
  </asset>
  <worldbody>
    <light pos="0.5 -0.5 1.6" dir="0 0.4 -1" diffuse="0.8 0.8 0.8"/>
    <light pos="0.5 0.5 1.6" dir="0 -0.4 -1" diffuse="0.3 0.3 0.3" castshadow="false"/>
    <geom name="floor" type="plane" size="2 2 0.1" material="grid"/>
    <geom name="table" type="box" pos="{c.table_xy[0]} {c.table_xy[1]} {c.table_height / 2}"
          size="0.35 0.45 {c.table_height / 2}" rgba="0.62 0.48 0.32 1"/>
    {cams}
    <body name="hand" gravcomp="1">
      <joint name="hx" type="slide" axis="1 0 0"/>
      <joint name="hy" type="slide" axis="0 1 0"/>
      <joint name="hz" type="slide" axis="0 0 1"/>
      <joint name="yaw" type="hinge" axis="0 0 1" damping="1"/>
      <geom name="palm" type="box" size="0.02 {open_y + fy:.6g} 0.01" mass="0.6" rgba="0.6 0.6 0.65 1"
            contype="0" conaffinity="0"/>
      {fingers}
    </body>
    <body name="object" pos="{c.object_xy[0]} {c.object_xy[1]} {z0:.6g}" euler="0 0 {c.object_yaw}">
      <freejoint/>
      <geom name="object" type="mesh" mesh="object" mass="{mass:.6g}" friction="{c.friction} 0.02 0.0001"
            rgba="{_fmt(c.object_color)}" condim="4"/>
    </body>
  </worldbody>
  <equality><joint joint1="right" joint2="left" polycoef="0 1 0 0 0" solref="0.005 1"/></equality>
  <actuator>
    <position name="hx" joint="hx" kp="{c.hand_kp}" kv="{kv:.6g}"/>
    <position name="hy" joint="hy" kp="{c.hand_kp}" kv="{kv:.6g}"/>
    <position name="hz" joint="hz" kp="{c.hand_kp}" kv="{kv:.6g}"/>
    <position name="yaw" joint="yaw" kp="50" kv="2"/>
    <motor name="grip_left" joint="left" ctrlrange="{-c.max_grip_force} {c.max_grip_force}"/>
    <motor name="grip_right" joint="right" ctrlrange="{-c.max_grip_force} {c.max_grip_force}"/>
  </actuator>
</mujoco>
"""


class MujocoScene:
    """A headless MuJoCo world with the table, the floating gripper and one object.

    Args:
        mesh: the object's mesh in any frame and scale (scaled to ``cfg.object_size`` and re-centred).
        cfg: scene geometry and physics.
        cameras: name -> (eye (3,), target (3,), fovy degrees) of the fixed cameras to add.
    """

    def __init__(
        self, mesh: trimesh.Trimesh, cfg: MujocoSceneConfig | None = None, cameras: dict[str, tuple] | None = None
    ) -> None:
        self.cfg = cfg or MujocoSceneConfig()
        self.mesh = prepare_object_mesh(mesh, self.cfg.object_size)  # body frame, metres
        self.model = mujoco.MjModel.from_xml_string(gripper_xml(self.mesh, self.cfg, cameras))
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.object_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        self.object_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
        self.hand_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in ("hx", "hy", "hz", "yaw")])
        self.finger_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in ("left", "right")])
        self.mass = float(m.body_mass[self.object_body])
        self.data.qpos[self.hand_qpos] = [*self.cfg.hand_start, 0.0]
        self.data.ctrl[:4] = [*self.cfg.hand_start, 0.0]
        self.grip(-10.0)  # hold the fingers open
        mujoco.mj_forward(m, self.data)
        self.settle(150)

    # ------------------------------------------------------------------ control
    def command_hand(self, grasp_point: np.ndarray, yaw: float) -> None:
        """Servo the hand so the point between the pads goes to ``grasp_point`` (3,) with the hand at ``yaw``."""
        self.data.ctrl[:3] = np.asarray(grasp_point, np.float64) + np.array([0.0, 0.0, PAD_BELOW_HAND])
        self.data.ctrl[3] = float(yaw)

    def commanded_grasp_point(self) -> np.ndarray:
        """(3,) float64 where :meth:`command_hand` last sent the point between the pads."""
        return np.array(self.data.ctrl[:3]) - np.array([0.0, 0.0, PAD_BELOW_HAND])

    def grip(self, force: float) -> None:
        """Drive each finger with ``force`` N (> 0 closes, < 0 opens): one motor per finger, the equality only
        keeps them symmetric about the hand."""
        self.data.ctrl[4:6] = float(np.clip(force, -self.cfg.max_grip_force, self.cfg.max_grip_force))

    def step(self, n: int = 1) -> None:
        """Advance the physics ``n`` steps."""
        mujoco.mj_step(self.model, self.data, nstep=int(n))

    def settle(self, steps: int) -> None:
        """Step the world ``steps`` times with the current controls."""
        self.step(steps)

    # ------------------------------------------------------------------ state
    def grasp_point(self) -> np.ndarray:
        """(3,) float64 world point between the pads (the hand frame ``PAD_BELOW_HAND`` below the hand)."""
        return np.array(self.data.xpos[self.model.body("hand").id]) - np.array([0.0, 0.0, PAD_BELOW_HAND])

    def object_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) position, (4,) wxyz quaternion) float64 of the object's body frame in world."""
        return np.array(self.data.xpos[self.object_body]), np.array(self.data.xquat[self.object_body])

    def object_mesh_world(self) -> trimesh.Trimesh:
        """The object's mesh geom surface in world coordinates (a new trimesh)."""
        from tvrecon.robot.mujoco.sensor import geom_mesh

        T = np.eye(4)
        T[:3, :3] = np.asarray(self.data.geom_xmat[self.object_geom]).reshape(3, 3)
        T[:3, 3] = self.data.geom_xpos[self.object_geom]
        return geom_mesh(self.model, self.object_geom).apply_transform(T)

    def finger_positions(self) -> np.ndarray:
        """(2,) float64 how far each finger has closed from open (metres)."""
        return np.array(self.data.qpos[self.finger_qpos])
