"""One pick-and-place in MuJoCo, step by step (the demo's driver is :mod:`tvrecon.robot.mujoco.pick_place`).

:class:`PickPlaceRun` holds the scene (:mod:`tvrecon.robot.mujoco.scene`), the two pads'
:class:`~tvrecon.robot.mujoco.sensor.TactileSensor` sharing one EIP solver, the cameras and the per-frame log, and
moves the floating gripper along straight Cartesian lines; :func:`plan_grasp` finds the object in the scene's rendered
RGB-D + segmentation image (or, without a renderer, the model's geometry) and plans the top grasp
(``tvrecon.robot.grasp.plan_top_grasp``); :func:`execute` runs the phases (approach, contact, squeeze, lift,
carry, place, release) and says where and why a run failed.
"""

from __future__ import annotations

import numpy as np
import trimesh
from tqdm.auto import tqdm

from tvrecon.robot.grasp import GraspPlan, plan_top_grasp
from tvrecon.robot.mujoco.camera import MujocoCamera, RendererUnavailable
from tvrecon.robot.mujoco.pick_place_config import MujocoPickPlaceConfig
from tvrecon.robot.mujoco.scene import FINGER_HALF, MAX_OPENING, MujocoScene
from tvrecon.robot.mujoco.sensor import TactileSensor
from tvrecon.robot.pad_reading import FingerReading, reading_record
from tvrecon.robot.pad_sensor import LazySimulator, sense_pads
from tvrecon.robot.pick_place_common import PHASES

__all__ = ["PickPlaceRun", "execute", "plan_grasp", "yaw_for"]


class PickPlaceRun:
    """The scene, its pads and cameras, and the per-frame log of one run."""

    def __init__(self, cfg: MujocoPickPlaceConfig, mesh: trimesh.Trimesh, simulator: object | None) -> None:
        self.cfg = cfg
        c = cfg.camera
        W, H = cfg.render_size
        cams = {"perception": (c.eye, c.target, c.fov), "render": (cfg.render_eye, cfg.render_target, 48.0)}
        self.scene = MujocoScene(mesh, cfg.scene, cameras=cams)
        m, d = self.scene.model, self.scene.data
        sim = simulator if simulator is not None else LazySimulator(cfg.pad)  # one solver for both pads
        self.pads = tuple(
            TactileSensor(
                m,
                d,
                geom=f"{side}_pad",
                pad=cfg.pad,
                normal_axis=(0, -sgn, 0),
                up_axis=(0, 0, 1),
                objects=[self.scene.object_geom],
                simulator=sim,
                name=side,
            )
            for side, sgn in (("left", 1), ("right", -1))
        )
        self.camera = self.view = None
        self.render_note = ""
        if not cfg.render:
            tqdm.write(
                "warning: render=false: the grasp is planned from the simulator's own object mesh (ground truth)"
            )
        if cfg.render:
            try:
                self.camera = MujocoCamera(m, "perception", c.width, c.height)
                self.view = MujocoCamera(m, "render", W, H)
            except RendererUnavailable as err:
                self.render_note = str(err)
                tqdm.write(f"warning: {err}; planning the grasp from the model's object geometry, no video")
        self.records: list[dict] = []
        self.perception: dict | None = None  # the perception camera's shot the grasp was planned from (execute)
        self.phase, self.fresh, self.steps = "approach", True, 0
        self.yaw = 0.0
        self.grip_force = -10.0
        self.bar = tqdm(total=None, desc="mujoco pick-place", unit="step", disable=not cfg.progress)

    # ------------------------------------------------------------------ low level
    def set_phase(self, name: str) -> None:
        self.phase, self.fresh = name, True
        self.bar.set_postfix_str(name)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.scene.grip(self.grip_force)
            self.scene.step()
            self.steps += 1
            if self.steps % self.cfg.frame_every == 0:
                self.record()
        self.bar.update(n)

    def seconds(self, t: float) -> int:
        return max(1, round(t / self.scene.cfg.time_step))

    def touching(self) -> list[bool]:
        return [sum(p.force for p in pad.contact_points()) >= pad.pad.min_force for pad in self.pads]

    def frame(self) -> np.ndarray:
        if self.view is None:
            W, H = self.cfg.render_size
            return np.zeros((H, W, 3), np.uint8)
        return self.view.rgb(self.scene.data)

    def record(self) -> None:
        readings: list[FingerReading] = sense_pads(self.pads, refresh=self.fresh)
        self.fresh = False
        s = self.scene
        pos, quat = s.object_pose()
        self.records.append(
            {
                "step": self.steps,
                "time": self.steps * s.cfg.time_step,
                "phase": PHASES.index(self.phase),
                "object_pos": pos,
                "object_quat": quat,
                "ee_pos": s.grasp_point(),
                "finger_q": s.finger_positions(),
                **reading_record(readings),
                "patch_points": np.array([len(r.patch) for r in readings]),
                "frame": self.frame(),
            }
        )

    # ------------------------------------------------------------------ motions
    def move_to(self, target: np.ndarray, speed: float | None = None) -> None:
        """Straight line of the grasp point to ``target`` (smoothstep in time), then settle."""
        start = self.scene.commanded_grasp_point()
        dist = float(np.linalg.norm(target - start))
        n = max(2, int(np.ceil(dist / ((speed or self.cfg.speed) * self.scene.cfg.time_step))))
        for k in range(1, n + 1):
            s = k / n
            s = s * s * (3 - 2 * s)  # zero velocity at both ends
            self.scene.command_hand(start + s * (target - start), self.yaw)
            self.step()
        self.step(self.seconds(self.cfg.settle_time))

    def supported(self) -> bool:
        """Whether the object touches anything but the pads (the table)."""
        d, s = self.scene.data, self.scene
        pads = {p.geom for p in self.pads}
        for g1, g2 in np.asarray(d.contact.geom[: d.ncon]):
            if s.object_geom in (g1, g2) and not ({int(g1), int(g2)} & pads):
                return True
        return False

    def lower_until_supported(self, speed: float = 0.02, max_drop: float = 0.03) -> bool:
        """Lower the grasp point at ``speed`` m/s until the held object touches the table (at most ``max_drop``)."""
        start = self.scene.commanded_grasp_point()
        n = self.seconds(max_drop / speed)
        for k in range(1, n + 1):
            if self.supported():
                break
            self.scene.command_hand(start - np.array([0.0, 0.0, max_drop * k / n]), self.yaw)
            self.step()
        self.step(self.seconds(self.cfg.settle_time))
        return self.supported()

    def close_until_contact(self, timeout: float = 2.0) -> bool:
        """Close with the contact force until both pads touch (or the fingers are shut)."""
        self.grip_force = self.cfg.contact_force
        for _ in range(self.seconds(timeout)):
            self.step()
            if all(self.touching()):
                return True
            if self.scene.finger_positions().min() > MAX_OPENING / 2 - 5e-3:  # shut (the pads meet)
                return False
        return all(self.touching())


def yaw_for(closing_axis: np.ndarray) -> float:
    """Hand yaw whose y axis (the fingers' travel) lies along ``closing_axis``, folded into [-pi/2, pi/2]."""
    yaw = float(np.arctan2(-closing_axis[0], closing_axis[1]))
    if yaw > np.pi / 2:
        yaw -= np.pi
    elif yaw < -np.pi / 2:
        yaw += np.pi
    return yaw


def plan_grasp(run: PickPlaceRun) -> tuple[GraspPlan, dict | None]:
    """The top grasp of the object from the perception camera's RGB-D + segmentation shot (its object pixels as
    world points), or from the model's object mesh where nothing renders; returns the plan and the shot (None)."""
    s = run.scene
    clearance = FINGER_HALF[2] + 0.004  # the pad's lower edge stays above the table
    if run.camera is not None:
        shot = run.camera.capture(s.data)
        points = shot["points"][shot["seg"] == s.object_geom]
    else:
        shot = None
        points = np.asarray(s.object_mesh_world().vertices)
    plan = plan_top_grasp(points, table_z=s.cfg.table_height, max_opening=MAX_OPENING, tip_clearance=clearance)
    return plan, shot


def execute(run: PickPlaceRun) -> tuple[bool, str, str, GraspPlan | None, float]:
    """The task; returns (success, message, phase reached, plan, placement error in metres)."""
    cfg, s = run.cfg, run.scene
    plan, shot = plan_grasp(run)
    run.perception = shot
    run.record()
    if not plan.feasible:
        return False, plan.reason, "approach", plan, float("nan")
    run.yaw = yaw_for(plan.closing_axis)
    up = np.array([0.0, 0.0, cfg.approach_height])

    run.set_phase("approach")
    run.move_to(plan.position + up)
    run.move_to(plan.position, speed=cfg.speed / 2)

    run.set_phase("contact")
    if not run.close_until_contact():
        msg = f"grasp failed: the pads closed without touching both sides (planned width {plan.width * 100:.1f} cm)"
        return False, msg, "contact", plan, float("nan")
    run.step(run.seconds(0.02))

    run.set_phase("squeeze")
    n = run.seconds(cfg.squeeze_time)
    for k in range(n):  # ramp the grip force to its full value over the first half, then hold
        run.grip_force = cfg.contact_force + (cfg.grip_force - cfg.contact_force) * min(1.0, 2.0 * (k + 1) / n)
        run.step()

    z0 = s.object_pose()[0][2]
    run.set_phase("lift")
    lifted = plan.position + np.array([0.0, 0.0, cfg.lift_height])
    run.move_to(lifted, speed=cfg.speed / 2)
    rise = s.object_pose()[0][2] - z0
    if rise < 0.7 * cfg.lift_height or not all(run.touching()):
        msg = f"grasp failed: the object slipped (rose {rise * 100:.1f} cm of {cfg.lift_height * 100:.1f} cm)"
        return False, msg, "lift", plan, float("nan")

    run.set_phase("carry")
    offset = np.array([cfg.place_xy[0], cfg.place_xy[1], 0.0]) - np.array([*plan.position[:2], 0.0])
    run.move_to(lifted + offset)
    if not all(run.touching()):
        return False, "grasp failed: the object was dropped while carrying", "carry", plan, float("nan")

    run.set_phase("place")
    run.move_to(plan.position + offset + np.array([0.0, 0.0, 0.01]), speed=cfg.speed / 2)
    run.lower_until_supported()  # set it down instead of dropping it: a tilted or round object rolls off a drop

    run.set_phase("release")
    run.grip_force = -10.0
    run.step(run.seconds(cfg.release_time))
    run.move_to(plan.position + offset + up)
    run.step(2 * cfg.frame_every)
    err = float(np.linalg.norm(s.object_pose()[0][:2] - np.asarray(cfg.place_xy)))
    if err > 0.03:
        return False, f"placed {err * 100:.1f} cm away from the target (tolerance 3 cm)", "release", plan, err
    return True, f"picked and placed: object {err * 100:.1f} cm from the target", "release", plan, err
