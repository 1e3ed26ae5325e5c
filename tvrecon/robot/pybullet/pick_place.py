"""Pick-and-place with EIP tactile fingers: a Panda on a table picks an object, lifts, carries, places, releases.

Run::

    python -m tvrecon.robot.pybullet.pick_place object=can
    python -m tvrecon.robot.pybullet.pick_place object=/path/to/mesh.obj scene.object_size=0.09 \
        out_dir=outputs/robot_mesh

The object is located from the scene's own RGB-D + segmentation camera (no ground-truth pose), the grasp is
planned from that point cloud, the arm follows Cartesian waypoints through pybullet's inverse kinematics, and each
finger's :class:`~tvrecon.robot.pybullet.finger.TactileFinger` turns its pybullet contacts into EIP tactile images in
every control phase. Writes ``pick_place.gif``, ``pick_place_strip.png`` and ``pick_place_log.npz``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from tvrecon.robot.grasp import GraspPlan, plan_top_grasp
from tvrecon.robot.pad_sensor import LazySimulator
from tvrecon.robot.pick_place_common import PHASES, load_object_mesh
from tvrecon.robot.pybullet.camera import RGBDCamera
from tvrecon.robot.pybullet.controller import ArmController, hand_orientation
from tvrecon.robot.pybullet.finger import TactileFinger
from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig
from tvrecon.robot.pybullet.scene import PANDA_FINGER_LINKS, PANDA_MAX_OPENING, Scene
from tvrecon.utils.atomic import atomic_open
from tvrecon.utils.output_dir import announce

__all__ = ["PickPlaceResult", "run_pick_place", "main"]

PANDA_PAD_CENTER = (0.0, 0.0, 0.044)  # centre of the flat inner face of panda's finger collision mesh (link frame)


@dataclass
class PickPlaceResult:
    """Outcome of a run: success flag, message, phase reached, output paths, timings and the per-frame log."""

    success: bool
    message: str
    phase_reached: str
    plan: GraspPlan | None
    log: dict[str, np.ndarray]
    log_path: Path | None
    gif_path: Path | None
    strip_path: Path | None
    wall_time: float
    num_presses: int
    mp4_path: Path | None = None


def _atomic_savez(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with atomic_open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def run_pick_place(cfg: PickPlaceConfig | None = None, simulator: object | None = None) -> PickPlaceResult:
    """Run the whole pick-and-place and write the outputs.

    Args:
        cfg: the demo configuration (default: a can).
        simulator: an EIP simulator shared by both fingers (None builds one from ``cfg.pad``).

    Returns:
        A :class:`PickPlaceResult`; ``success`` is False with a clear ``message`` when the object cannot be held.
    """
    cfg = cfg or PickPlaceConfig()
    t0 = time.perf_counter()
    threads = torch.get_num_threads()
    if cfg.torch_threads is not None:
        torch.set_num_threads(int(cfg.torch_threads))
    try:
        return _run(cfg, simulator, t0)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: PickPlaceConfig, simulator: object | None, t0: float) -> PickPlaceResult:
    mesh = cfg.mesh if cfg.mesh is not None else load_object_mesh(cfg.object, cfg.seed)
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = Scene(mesh, cfg.scene)
    simulator = simulator if simulator is not None else LazySimulator(cfg.pad)  # one solver for both pads
    try:
        sides = zip(PANDA_FINGER_LINKS, ((0, -1, 0), (0, 1, 0)), ("left", "right"))  # pads face each other
        fingers = tuple(
            TactileFinger(
                scene.robot,
                link,
                normal_axis=normal,
                up_axis=(0, 0, 1),
                pad_center=PANDA_PAD_CENTER,
                pad=cfg.pad,
                simulator=simulator,
                client=scene.client,
                name=name,
            )
            for link, normal, name in sides
        )
        for f in fingers:
            f.attach_object(scene.object, scene.mesh)
        ctl = ArmController(scene, cfg, fingers)
        success, message, reached, plan = _execute(scene, cfg, ctl)
        ctl.bar.close()
        if not success:
            tqdm.write(f"pick-place FAILED: {message}")
        log = _collect_log(ctl, scene, plan, success, message, reached, cfg)
        log_path = out / "pick_place_log.npz"
        _atomic_savez(log_path, log)
        gif_path = mp4_path = strip_path = None
        if ctl.records and cfg.render and (cfg.write_gif or cfg.write_mp4 or cfg.write_strip):
            from tvrecon.robot.strip import write_gif, write_mp4, write_strip

            if cfg.write_gif:
                gif_path = write_gif(log, out / "pick_place.gif")
            if cfg.write_mp4:
                try:
                    mp4_path = write_mp4(log, out / "pick_place.mp4")
                except ImportError as err:
                    tqdm.write(f"warning: no MP4 written: {err}")
            if cfg.write_strip:
                strip_path = write_strip(log, out / "pick_place_strip.png")
        presses = sum(f.num_presses for f in fingers)
    finally:
        scene.close()
    return PickPlaceResult(
        success,
        message,
        reached,
        plan,
        log,
        log_path,
        gif_path,
        strip_path,
        time.perf_counter() - t0,
        presses,
        mp4_path,
    )


def object_misplaced(scene: Scene) -> str | None:
    """Why the object is not where the scene put it down (None if it is): it was knocked away while settling.

    An object much larger than the gripper (e.g. ``scene.object_size=2.0``) overlaps the robot or overhangs the table
    and is thrown out of the scene; the camera then sees nothing, which read as "too small to see".
    """
    c = scene.cfg
    pos = np.asarray(scene.object_pose()[0], dtype=np.float64)
    drift = float(np.linalg.norm(pos[:2] - np.asarray(c.object_xy, dtype=np.float64)))
    if drift <= 0.5 * c.object_size + 0.05 and pos[2] >= c.table_height:
        return None
    return (
        f"the object did not stay where it was put down (now at {np.round(pos, 2).tolist()} m, put down at "
        f"{list(c.object_xy)}): scene.object_size={c.object_size} m does not fit the scene (it hits the robot or "
        f"overhangs the table). The gripper opens {PANDA_MAX_OPENING * 100:.0f} cm: use an object_size of a few cm"
    )


def _execute(scene: Scene, cfg: PickPlaceConfig, ctl: ArmController) -> tuple[bool, str, str, GraspPlan | None]:
    """The task itself; returns (success, message, phase reached, plan)."""
    misplaced = object_misplaced(scene)
    if misplaced is not None:
        ctl.record()
        return False, misplaced, "approach", None
    cam = RGBDCamera(cfg.camera, client=scene.client)
    shot = cam.capture()
    ctl.perception = shot
    mask = shot["seg"] == scene.object
    plan = plan_top_grasp(shot["points"][mask], table_z=scene.cfg.table_height, max_opening=PANDA_MAX_OPENING)
    ctl.record()
    if not plan.feasible:
        return False, plan.reason, "approach", plan
    orn = hand_orientation(plan.closing_axis)
    above = plan.position + np.array([0.0, 0.0, cfg.approach_height])

    ctl.set_phase("approach")
    ctl.grip_target = PANDA_MAX_OPENING / 2
    ctl.move_to(above, orn)
    ctl.move_to(plan.position, orn, speed=cfg.speed / 2)

    ctl.set_phase("contact")
    ctl.grip_force = cfg.contact_force
    if not ctl.close_until_contact(max_steps=int(2 * PANDA_MAX_OPENING / (cfg.close_speed * scene.cfg.time_step))):
        return (
            False,
            (
                f"grasp failed: the fingers closed without touching the object on both sides (planned width "
                f"{plan.width * 100:.1f} cm)"
            ),
            "contact",
            plan,
        )
    ctl.hold(6)

    ctl.set_phase("squeeze")
    ctl.grip_speed = 0.2
    for k in range(cfg.squeeze_steps):  # ramp the grip force up to its full value, then hold
        ctl.grip_force = cfg.contact_force + (cfg.grip_force - cfg.contact_force) * min(
            1.0, 2.0 * (k + 1) / cfg.squeeze_steps
        )
        ctl.step()

    z0 = scene.object_pose()[0][2]
    ctl.set_phase("lift")
    lifted = plan.position + np.array([0.0, 0.0, cfg.lift_height])
    ctl.move_to(lifted, orn, speed=cfg.speed / 2)
    rise = scene.object_pose()[0][2] - z0
    if rise < 0.7 * cfg.lift_height or not all(len(f.contacts()) > 0 for f in ctl.fingers):
        return (
            False,
            (
                f"grasp failed: the object slipped out of the gripper (rose {rise * 100:.1f} cm of "
                f"{cfg.lift_height * 100:.1f} cm)"
            ),
            "lift",
            plan,
        )

    ctl.set_phase("carry")
    offset = np.array([cfg.place_xy[0], cfg.place_xy[1]]) - plan.position[:2]
    ctl.move_to(lifted + np.array([offset[0], offset[1], 0.0]), orn)
    if not all(len(f.contacts()) > 0 for f in ctl.fingers):
        return False, "grasp failed: the object was dropped while carrying", "carry", plan

    ctl.set_phase("place")
    place = plan.position + np.array([offset[0], offset[1], 0.003])
    ctl.move_to(place, orn, speed=cfg.speed / 2)

    ctl.set_phase("release")
    ctl.grip_target = PANDA_MAX_OPENING / 2
    ctl.grip_speed = 0.1
    ctl.hold(60)
    ctl.move_to(place + np.array([0.0, 0.0, cfg.approach_height]), orn)
    ctl.hold(2 * cfg.frame_every)
    final = scene.object_pose()[0]
    err = float(np.linalg.norm(final[:2] - np.asarray(cfg.place_xy)))
    if err > 0.03:
        return False, f"placed {err * 100:.1f} cm away from the target (tolerance 3 cm)", "release", plan
    return True, f"picked and placed: object {err * 100:.1f} cm from the target", "release", plan


def _collect_log(
    ctl: ArmController,
    scene: Scene,
    plan: GraspPlan | None,
    success: bool,
    message: str,
    reached: str,
    cfg: PickPlaceConfig,
) -> dict[str, np.ndarray]:
    recs = ctl.records
    keys = [k for k in recs[0] if k != "frame"] if recs else []
    log = {k: np.stack([np.asarray(r[k]) for r in recs]) for k in keys}
    log["frames"] = np.stack([r["frame"] for r in recs]).astype(np.uint8) if recs else np.zeros((0, 1, 1, 3), np.uint8)
    log["phase_names"] = np.array(PHASES)
    log["success"] = np.array(success)
    log["message"] = np.array(message)
    log["phase_reached"] = np.array(reached)
    log["object"] = np.array(cfg.object if cfg.mesh is None else "<mesh>")
    log["mesh_vertices"] = np.asarray(scene.mesh.vertices, dtype=np.float32)
    log["mesh_faces"] = np.asarray(scene.mesh.faces, dtype=np.int64)
    log["pad_size"] = np.array(cfg.pad.pad_size)
    log["pad_dx"] = np.array(cfg.pad.dx)
    if plan is not None:
        for k in ("position", "closing_axis", "centroid"):
            log[f"grasp_{k}"] = np.asarray(getattr(plan, k), dtype=np.float64)
        for k in ("yaw", "width", "length", "top_z", "n_points", "feasible"):
            log[f"grasp_{k}"] = np.array(getattr(plan, k))
    shot = getattr(ctl, "perception", None)
    if shot is not None:
        log["camera_rgb"], log["camera_depth"], log["camera_seg"] = shot["rgb"], shot["depth"], shot["seg"]
    return log


PROG = "python -m tvrecon.robot.pybullet.pick_place"


def _hydra_entry() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import DictConfig, OmegaConf

    from tvrecon.utils.cli_errors import hydra_task

    config_dir = str(Path(__file__).resolve().parents[3] / "configs" / "robot")

    outcome: dict[str, bool] = {}

    @hydra.main(version_base="1.3", config_path=config_dir, config_name="pick_place")
    @hydra_task(PROG)
    def _main(dcfg: DictConfig) -> None:
        d = OmegaConf.to_container(dcfg, resolve=True)
        if not d.get("out_dir"):
            d["out_dir"] = HydraConfig.get().runtime.output_dir
        cfg = PickPlaceConfig.from_dict(d)
        res = run_pick_place(cfg)
        outcome["success"] = bool(res.success)
        status = "OK" if res.success else "FAILED"
        print(f"[{status}] {res.message}")
        print(f"log: {res.log_path}\ngif: {res.gif_path}\nmp4: {res.mp4_path}\nstrip: {res.strip_path}")
        print(f"wall time {res.wall_time:.1f} s, {res.num_presses} EIP presses, {len(res.log.get('step', []))} frames")
        announce(d["out_dir"])  # the run's folder, the last line as every CLI's

    _main()
    if outcome.get("success") is False:  # scripts must tell a failed pick-place from a done one (logs are written)
        sys.exit(1)


def main() -> None:
    """Console entry point (Hydra): ``python -m tvrecon.robot.pybullet.pick_place object=can``.

    Exits with status 1 when the run ends ``[FAILED]`` (the log, gif and strip are still written), 0 on ``[OK]``;
    bad input (a missing or unreadable mesh, a wrong option) is one line on stderr and exit status 2, Ctrl-C 130
    (``tvrecon.utils.cli_errors``; ``--debug`` keeps the traceback).
    """
    from tvrecon.utils.cli_errors import run_hydra_cli

    run_hydra_cli(_hydra_entry, prog=PROG)


if __name__ == "__main__":
    main()
