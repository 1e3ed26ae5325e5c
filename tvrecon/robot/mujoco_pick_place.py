"""Pick-and-place in MuJoCo with EIP tactile pads: a floating parallel gripper picks, lifts, carries, places, releases.

Run (headless; ``MUJOCO_GL=egl`` is set when unset)::

    python -m tvrecon.robot.mujoco_pick_place object=can
    python -m tvrecon.robot.mujoco_pick_place object=duck          # pybullet_data's duck.obj
    python -m tvrecon.robot.mujoco_pick_place object=/path/to/mesh.obj scene.object_size=0.06

The object is found in the scene's own rendered RGB-D + segmentation image (MuJoCo's offscreen renderer; no
ground-truth pose), the grasp is planned from that point cloud (``tvrecon.robot.perception.plan_top_grasp``, as in
the pybullet demo), the gripper (``tvrecon.robot.mujoco_scene``) follows straight Cartesian lines, and each pad's
:class:`~tvrecon.robot.mujoco_sensor.TactileSensor` turns MuJoCo's contacts into EIP tactile images, both pads in
one batched solver call. Where MuJoCo cannot render (no EGL) the run says so in one line, plans the grasp from the
model's object geometry and writes the strip with blank scene frames and no video.

Writes ``mujoco_pick_place.gif`` / ``.mp4``, ``mujoco_pick_place_strip.png`` and ``mujoco_pick_place_log.npz`` (the
log keys of the pybullet demo, drawn by ``tvrecon.robot.strip``). Needs the ``[mujoco]`` and ``[robot]`` extras.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless offscreen rendering; read when mujoco is imported

import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
import trimesh  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

from tvrecon.robot.controller import PHASES  # noqa: E402
from tvrecon.robot.mujoco_camera import MujocoCamera, RendererUnavailable  # noqa: E402
from tvrecon.robot.mujoco_scene import FINGER_HALF, MAX_OPENING, MujocoScene, MujocoSceneConfig  # noqa: E402
from tvrecon.robot.mujoco_sensor import TactileSensor  # noqa: E402
from tvrecon.robot.pad import LazySimulator, sense_pads
from tvrecon.robot.pad_config import PadConfig  # noqa: E402
from tvrecon.robot.pad_reading import FingerReading, reading_record
from tvrecon.robot.perception import GraspPlan, plan_top_grasp  # noqa: E402
from tvrecon.utils.atomic import atomic_open  # noqa: E402
from tvrecon.utils.config_utils import coerce_config  # noqa: E402

__all__ = ["MujocoPickPlaceConfig", "MujocoPickPlaceResult", "resolve_object_mesh", "run_mujoco_pick_place", "main"]


@dataclass
class MujocoCameraConfig:
    """A fixed camera at ``eye`` looking at ``target`` (world metres), ``fov`` degrees vertical, ``width`` x
    ``height`` pixels."""

    eye: tuple[float, float, float] = (0.78, 0.0, 0.95)
    target: tuple[float, float, float] = (0.5, 0.02, 0.4)
    fov: float = 58.0
    width: int = 256
    height: int = 256


@dataclass
class MujocoPickPlaceConfig:
    """Everything the MuJoCo demo needs (mirrors ``configs/robot/mujoco_pick_place.yaml``).

    object: a procedural class (``tvrecon.data.shapes``), a ``pybullet_data`` mesh name (``duck``) or a mesh path.
    place_xy: (2,) where the object is put down. lift_height: metres above the grasp height. speed: m/s of the
    grasp point. contact_force / grip_force: N per finger while closing / after the squeeze. squeeze_time,
    settle_time, release_time: seconds. frame_every: physics steps per logged frame (each logged frame reads the
    pads). render_size: (W, H) of the scene frames.
    """

    object: str = "can"
    seed: int = 0
    mesh: trimesh.Trimesh | None = None  # a mesh given directly through the Python API (overrides ``object``)
    place_xy: tuple[float, float] = (0.5, 0.15)
    approach_height: float = 0.10
    lift_height: float = 0.12
    speed: float = 0.2
    contact_force: float = 6.0
    grip_force: float = 40.0
    squeeze_time: float = 0.4
    settle_time: float = 0.16
    release_time: float = 0.3
    frame_every: int = 10
    render: bool = True
    render_size: tuple[int, int] = (256, 192)
    render_eye: tuple[float, float, float] = (0.92, 0.0, 0.78)
    render_target: tuple[float, float, float] = (0.5, 0.0, 0.5)
    out_dir: str = "outputs/robot_mujoco"
    write_gif: bool = True
    write_mp4: bool = True
    write_strip: bool = True
    progress: bool = True
    torch_threads: int | None = 1
    scene: MujocoSceneConfig = field(default_factory=MujocoSceneConfig)
    camera: MujocoCameraConfig = field(default_factory=MujocoCameraConfig)
    pad: PadConfig = field(default_factory=PadConfig)

    @classmethod
    def from_dict(cls, d: dict) -> MujocoPickPlaceConfig:
        """Build from a plain (Hydra/OmegaConf container) dict; nested dicts fill the nested dataclasses."""
        return coerce_config(cls, d, "mujoco_pick_place")


@dataclass
class MujocoPickPlaceResult:
    """Outcome of a run: success, message, phase reached, placement error (m), outputs, timings and the log."""

    success: bool
    message: str
    phase_reached: str
    plan: GraspPlan | None
    placement_error: float
    log: dict[str, np.ndarray]
    log_path: Path | None
    gif_path: Path | None
    mp4_path: Path | None
    strip_path: Path | None
    wall_time: float
    num_presses: int
    rendered: bool


def resolve_object_mesh(name_or_path: str, seed: int = 0) -> trimesh.Trimesh:
    """A library class (``make_shape``), a ``pybullet_data`` mesh by name (``duck`` -> ``duck.obj``) or a mesh file."""
    from tvrecon.data.shapes import CLASSES
    from tvrecon.robot.pick_place import load_object_mesh

    name = str(name_or_path)
    if name not in CLASSES and not Path(name).suffix:
        try:
            import pybullet_data
        except ImportError:
            pybullet_data = None
        if pybullet_data is not None:
            path = Path(pybullet_data.getDataPath()) / f"{name}.obj"
            if path.exists():
                return load_object_mesh(str(path), seed)
    return load_object_mesh(name, seed)


class _Run:
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
        if cfg.render:
            try:
                self.camera = MujocoCamera(m, "perception", c.width, c.height)
                self.view = MujocoCamera(m, "render", W, H)
            except RendererUnavailable as err:
                self.render_note = str(err)
                tqdm.write(f"warning: {err}; planning the grasp from the model's object geometry, no video")
        self.records: list[dict] = []
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


def _yaw_for(closing_axis: np.ndarray) -> float:
    """Hand yaw whose y axis (the fingers' travel) lies along ``closing_axis``, folded into [-pi/2, pi/2]."""
    yaw = float(np.arctan2(-closing_axis[0], closing_axis[1]))
    if yaw > np.pi / 2:
        yaw -= np.pi
    elif yaw < -np.pi / 2:
        yaw += np.pi
    return yaw


def _plan(run: _Run) -> tuple[GraspPlan, dict | None]:
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


def _execute(run: _Run) -> tuple[bool, str, str, GraspPlan | None, float]:
    """The task; returns (success, message, phase reached, plan, placement error in metres)."""
    cfg, s = run.cfg, run.scene
    plan, shot = _plan(run)
    run.perception = shot
    run.record()
    if not plan.feasible:
        return False, plan.reason, "approach", plan, float("nan")
    run.yaw = _yaw_for(plan.closing_axis)
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


def _collect_log(run: _Run, plan: GraspPlan | None, outcome: tuple, cfg: MujocoPickPlaceConfig) -> dict:
    success, message, reached, _, err = outcome
    recs = run.records
    keys = [k for k in recs[0] if k != "frame"] if recs else []
    log = {k: np.stack([np.asarray(r[k]) for r in recs]) for k in keys}
    log["frames"] = np.stack([r["frame"] for r in recs]).astype(np.uint8) if recs else np.zeros((0, 1, 1, 3), np.uint8)
    log["phase_names"] = np.array(PHASES)
    log["success"] = np.array(success)
    log["message"] = np.array(f"MuJoCo: {message}")
    log["phase_reached"] = np.array(reached)
    log["placement_error"] = np.array(err)
    log["object"] = np.array(cfg.object if cfg.mesh is None else "<mesh>")
    log["mesh_vertices"] = np.asarray(run.scene.mesh.vertices, dtype=np.float32)
    log["mesh_faces"] = np.asarray(run.scene.mesh.faces, dtype=np.int64)
    log["pad_size"] = np.array(cfg.pad.pad_size)
    log["pad_dx"] = np.array(cfg.pad.dx)
    log["rendered"] = np.array(run.view is not None)
    if plan is not None:
        for k in ("position", "closing_axis", "centroid"):
            log[f"grasp_{k}"] = np.asarray(getattr(plan, k), dtype=np.float64)
        for k in ("width", "length", "top_z", "n_points", "feasible"):
            log[f"grasp_{k}"] = np.array(getattr(plan, k))
    shot = getattr(run, "perception", None)
    if shot is not None:
        log["camera_rgb"], log["camera_depth"], log["camera_seg"] = shot["rgb"], shot["depth"], shot["seg"]
    return log


def run_mujoco_pick_place(
    cfg: MujocoPickPlaceConfig | None = None, simulator: object | None = None
) -> MujocoPickPlaceResult:
    """Run the whole pick-and-place in MuJoCo and write the outputs.

    Args:
        cfg: the demo configuration (default: the can).
        simulator: an EIP simulator shared by both pads (None builds one from ``cfg.pad``).

    Returns:
        A :class:`MujocoPickPlaceResult`; ``success`` False with a clear ``message`` when the object is not placed.
    """
    cfg = cfg or MujocoPickPlaceConfig()
    t0 = time.perf_counter()
    threads = torch.get_num_threads()
    if cfg.torch_threads is not None:
        torch.set_num_threads(int(cfg.torch_threads))
    try:
        mesh = cfg.mesh if cfg.mesh is not None else resolve_object_mesh(cfg.object, cfg.seed)
        out = Path(cfg.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        run = _Run(cfg, mesh, simulator)
        outcome = _execute(run)
        run.bar.close()
        if not outcome[0]:
            tqdm.write(f"mujoco pick-place FAILED: {outcome[1]}")
        log = _collect_log(run, outcome[3], outcome, cfg)
        log_path = out / "mujoco_pick_place_log.npz"
        with atomic_open(log_path, "wb") as fh:
            np.savez_compressed(fh, **log)
        gif = mp4 = strip = None
        if run.records:
            from tvrecon.robot.strip import write_gif, write_mp4, write_strip

            if cfg.write_strip:
                strip = write_strip(log, out / "mujoco_pick_place_strip.png")
            if run.view is not None and cfg.write_gif:
                gif = write_gif(log, out / "mujoco_pick_place.gif")
            if run.view is not None and cfg.write_mp4:
                try:
                    mp4 = write_mp4(log, out / "mujoco_pick_place.mp4")
                except ImportError as err:
                    tqdm.write(f"warning: no MP4 written: {err}")
        for cam in (run.camera, run.view):
            if cam is not None:
                cam.close()
    finally:
        torch.set_num_threads(threads)
    success, message, reached, plan, err = outcome
    presses = sum(p.num_presses for p in run.pads)
    wall = time.perf_counter() - t0
    rendered = run.view is not None
    return MujocoPickPlaceResult(
        success, message, reached, plan, err, log, log_path, gif, mp4, strip, wall, presses, rendered
    )


def _hydra_entry() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig, OmegaConf

    config_dir = str(Path(__file__).resolve().parents[2] / "configs" / "robot")
    outcome: dict[str, bool] = {}

    @hydra.main(version_base="1.3", config_path=config_dir, config_name="mujoco_pick_place")
    def _main(dcfg: DictConfig) -> None:
        d = OmegaConf.to_container(dcfg, resolve=True)
        if not d.get("out_dir"):
            d["out_dir"] = HydraConfig.get().runtime.output_dir
        res = run_mujoco_pick_place(MujocoPickPlaceConfig.from_dict(d))
        outcome["success"] = bool(res.success)
        print(f"[{'OK' if res.success else 'FAILED'}] {res.message}")
        print(f"log: {res.log_path}\ngif: {res.gif_path}\nmp4: {res.mp4_path}\nstrip: {res.strip_path}")
        print(f"wall time {res.wall_time:.1f} s, {res.num_presses} EIP presses, {len(res.log.get('step', []))} frames")

    _main()
    if outcome.get("success") is False:  # scripts must tell a failed run from a done one (outputs are written)
        sys.exit(1)


def main() -> None:
    """Console entry point (Hydra): ``python -m tvrecon.robot.mujoco_pick_place object=can``; exit 1 on [FAILED]."""
    _hydra_entry()


if __name__ == "__main__":
    main()
