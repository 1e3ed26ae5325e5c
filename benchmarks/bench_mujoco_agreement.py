"""The same squeeze in pybullet and MuJoCo: do the two engines' tactile images agree? (issue 26, item 3)

Scene, identical in both engines (no gravity): an object of the library standing fixed at the origin (the
pick-and-place's prepared mesh, 6.5 cm), and one finger, the MuJoCo gripper's pad box (2.2 x 1 x 3.2 cm), on a
prismatic joint along +y, pushed against the object's side by a motor of ``--force`` newtons until it settles. The
pybullet :class:`~tvrecon.robot.pybullet.finger.TactileFinger` and the MuJoCo
:class:`~tvrecon.robot.mujoco.sensor.TactileSensor` then read the pad with the same :class:`PadConfig` (same EIP
press code behind both, ``tvrecon.robot.pad_sensor``). What can differ is what each engine hands the pad: the contact
force (the press depth is max(penetration, force / stiffness)), the penetration, the contact points, and the finger's
settled pose (position along the object, tilt).

Prints, per object, each engine's force, penetration, press depth and press centre, and the Pearson correlation of
its normal-displacement image (and of all three channels) with pybullet's: MuJoCo with the sensor's default depth
(the pad's give under MuJoCo's force) and with ``use_penetration=True`` (at least MuJoCo's soft-contact overlap).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_mujoco_agreement.py [--objects can cube pear] [--force 20]``.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pybullet as p  # noqa: E402
import torch  # noqa: E402

from tvrecon.data.shapes import make_shape  # noqa: E402
from tvrecon.robot.mujoco.scene import FINGER_HALF, _fmt  # noqa: E402
from tvrecon.robot.mujoco.sensor import TactileSensor  # noqa: E402
from tvrecon.robot.pad_config import PadConfig  # noqa: E402
from tvrecon.robot.pad_reading import FingerReading
from tvrecon.robot.pad_sensor import LazySimulator
from tvrecon.robot.pick_place_common import prepare_object_mesh  # noqa: E402
from tvrecon.robot.pybullet.finger import TactileFinger  # noqa: E402
from tvrecon.robot.pybullet.scene import collision_shape_for_mesh  # noqa: E402


def corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.ravel(a) - np.mean(a), np.ravel(b) - np.mean(b)
    den = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(a @ b / den) if den > 0 else float("nan")


def start_y(mesh) -> float:
    """Finger centre y where its face clears the object's side by 2 mm."""
    return float(mesh.bounds[0, 1]) - FINGER_HALF[1] - 0.002


def pybullet_squeeze(mesh, pad: PadConfig, sim: LazySimulator, force: float, steps: int = 480) -> FingerReading:
    cid = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, 0, physicsClientId=cid)
        p.setPhysicsEngineParameter(fixedTimeStep=1 / 240, numSolverIterations=150, physicsClientId=cid)
        col, _ = collision_shape_for_mesh(mesh, cid)
        obj = p.createMultiBody(0.0, col, basePosition=(0, 0, 0), physicsClientId=cid)
        box = p.createCollisionShape(p.GEOM_BOX, halfExtents=FINGER_HALF, physicsClientId=cid)
        finger = p.createMultiBody(
            baseMass=0.0,
            basePosition=(0, start_y(mesh), 0),
            linkMasses=[0.05],
            linkCollisionShapeIndices=[box],
            linkVisualShapeIndices=[-1],
            linkPositions=[(0, 0, 0)],
            linkOrientations=[(0, 0, 0, 1)],
            linkInertialFramePositions=[(0, 0, 0)],
            linkInertialFrameOrientations=[(0, 0, 0, 1)],
            linkParentIndices=[0],
            linkJointTypes=[p.JOINT_PRISMATIC],
            linkJointAxis=[(0, 1, 0)],
            physicsClientId=cid,
        )
        p.changeDynamics(finger, 0, lateralFriction=1.5, physicsClientId=cid)
        p.setJointMotorControl2(
            finger, 0, p.POSITION_CONTROL, targetPosition=0.05, force=force, maxVelocity=0.05, physicsClientId=cid
        )
        for _ in range(steps):
            p.stepSimulation(physicsClientId=cid)
        f = TactileFinger(finger, 0, normal_axis=(0, 1, 0), up_axis=(0, 0, 1), pad_center=(0, 0, 0), pad=pad,
                          simulator=sim, client=cid, name="pybullet")  # fmt: skip
        f.attach_object(obj, mesh)
        return f.sense(refresh=True)
    finally:
        p.disconnect(cid)


def mujoco_squeeze(
    mesh, pad: PadConfig, sim: LazySimulator, force: float, steps: int = 1000, **sensor_kw: object
) -> FingerReading:
    fx, fy, fz = FINGER_HALF
    faces = " ".join(str(int(i)) for i in np.ravel(mesh.faces))
    xml = f"""<mujoco><option gravity="0 0 0" timestep="0.002" cone="elliptic" impratio="10"/>
      <asset><mesh name="obj" vertex="{_fmt(mesh.vertices)}" face="{faces}" inertia="convex"/></asset>
      <worldbody><geom name="obj" type="mesh" mesh="obj"/>
        <body name="finger" pos="0 {start_y(mesh):.6g} 0"><joint name="slide" type="slide" axis="0 1 0" damping="20"/>
          <geom name="pad" type="box" size="{fx} {fy} {fz}" mass="0.05" friction="1.5 0.02 0.0001" condim="4"
                solref="0.01 1"/></body>
      </worldbody>
      <actuator><motor joint="slide" ctrlrange="-1000 1000"/></actuator></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.ctrl[0] = force
    mujoco.mj_step(model, data, nstep=steps)
    s = TactileSensor(
        model, data, geom="pad", pad=pad, normal_axis=(0, 1, 0), up_axis=(0, 0, 1), simulator=sim, **sensor_kw
    )
    return s.sense(refresh=True)  # presses the object geom's mesh asset (MuJoCo's recentred copy of ``mesh``)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", nargs="+", default=["can", "cube", "pear"])
    ap.add_argument("--force", type=float, default=20.0)
    ap.add_argument("--resolution", type=int, default=24)
    ap.add_argument("--n-grid", type=int, default=64)
    args = ap.parse_args()
    torch.set_num_threads(1)
    pad = PadConfig(resolution=(args.resolution, args.resolution), n_grid=args.n_grid)
    sim = LazySimulator(pad)
    print(f"squeeze {args.force} N, pad {args.resolution}x{args.resolution}x{pad.layers} on n_grid {args.n_grid}")
    print("| object | engine | force N | penetration mm | depth mm | press centre y, z mm | corr normal | corr all |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.objects:
        mesh = prepare_object_mesh(make_shape(name, seed=0), 0.065)
        rb = pybullet_squeeze(mesh, pad, sim, args.force)
        runs = (
            ("pybullet", rb),
            ("mujoco", mujoco_squeeze(mesh, pad, sim, args.force)),
            ("mujoco use_penetration", mujoco_squeeze(mesh, pad, sim, args.force, use_penetration=True)),
        )
        for eng, r in runs:
            pos = r.position * 1e3
            print(
                f"| {name} | {eng} | {r.force:.2f} | {r.penetration * 1e3:.3f} | {r.depth * 1e3:.2f} | "
                f"{pos[1]:.2f}, {pos[2]:.2f} | {corr(rb.image[2], r.image[2]):.4f} | {corr(rb.image, r.image):.4f} |"
            )


if __name__ == "__main__":
    main()
