"""Pick-and-place in MuJoCo with EIP tactile pads: a floating parallel gripper picks, lifts, carries, places, releases.

Run (headless; ``MUJOCO_GL=egl`` is set when unset)::

    python -m tvrecon.robot.mujoco.pick_place object=can
    python -m tvrecon.robot.mujoco.pick_place object=duck          # pybullet_data's duck.obj
    python -m tvrecon.robot.mujoco.pick_place object=/path/to/mesh.obj scene.object_size=0.06

The object is found in the scene's own rendered RGB-D + segmentation image (MuJoCo's offscreen renderer; no
ground-truth pose), the grasp is planned from that point cloud (``tvrecon.robot.grasp.plan_top_grasp``, as in
the pybullet demo), the gripper (``tvrecon.robot.mujoco.scene``) follows straight Cartesian lines, and each pad's
:class:`~tvrecon.robot.mujoco.sensor.TactileSensor` turns MuJoCo's contacts into EIP tactile images, both pads in
one batched solver call. Where MuJoCo cannot render (no EGL) the run says so in one line, plans the grasp from the
model's object geometry and writes the strip with blank scene frames and no video.

Writes ``mujoco_pick_place.gif`` / ``.mp4``, ``mujoco_pick_place_strip.png`` and ``mujoco_pick_place_log.npz`` (the
log keys of the pybullet demo, drawn by ``tvrecon.robot.strip``). Needs the ``[mujoco]`` and ``[robot]`` extras.

This module is the driver: :func:`run_mujoco_pick_place` (the Python API), the log and outputs, the Hydra command
line. The configuration, outcome and object lookup are :mod:`tvrecon.robot.mujoco.pick_place_config`; the run itself
(scene, pads, cameras, motions, the task's phases) is :mod:`tvrecon.robot.mujoco.task`.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless offscreen rendering; read when mujoco is imported

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

# the camera module first: it imports mujoco with the fallback to MUJOCO_GL=disable where the backend has no OpenGL
# library
import tvrecon.robot.mujoco.camera  # noqa: E402, F401
from tvrecon.robot.grasp import GraspPlan  # noqa: E402
from tvrecon.robot.mujoco.camera import check_gl_setting  # noqa: E402
from tvrecon.robot.mujoco.pick_place_config import MujocoPickPlaceConfig, MujocoPickPlaceResult  # noqa: E402
from tvrecon.robot.mujoco.task import PickPlaceRun, execute  # noqa: E402
from tvrecon.robot.pick_place_common import PHASES, resolve_object_mesh  # noqa: E402
from tvrecon.utils.atomic import atomic_open  # noqa: E402
from tvrecon.utils.cli_errors import hydra_task, run_hydra_cli  # noqa: E402
from tvrecon.utils.output_dir import announce  # noqa: E402

__all__ = ["collect_log", "run_mujoco_pick_place", "main"]

PROG = "python -m tvrecon.robot.mujoco.pick_place"


def collect_log(run: PickPlaceRun, plan: GraspPlan | None, outcome: tuple, cfg: MujocoPickPlaceConfig) -> dict:
    """The run's log, the pybullet demo's keys (``tvrecon.robot.strip`` draws it): per logged frame (T frames) the
    step, time, phase, object and grasp-point poses, finger positions, both pads' readings and the (T, H, W, 3) uint8
    scene frames; then the outcome (``outcome``: :func:`~tvrecon.robot.mujoco.task.execute`'s tuple), the object
    mesh, the pad, the grasp ``plan`` and the perception camera's RGB-D + segmentation shot."""
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
    shot = run.perception
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
    if cfg.render:
        check_gl_setting()  # MUJOCO_GL=bogus: one line before anything is built
    try:
        mesh = cfg.mesh if cfg.mesh is not None else resolve_object_mesh(cfg.object, cfg.seed)
        out = Path(cfg.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        run = PickPlaceRun(cfg, mesh, simulator)
        outcome = execute(run)
        run.bar.close()
        if not outcome[0]:
            tqdm.write(f"mujoco pick-place FAILED: {outcome[1]}")
        log = collect_log(run, outcome[3], outcome, cfg)
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
    if run.camera is None:  # no perception: say it on the result's line, not only in a warning above the progress
        why = "render=false" if not cfg.render else "no renderer"
        message += f" [grasp planned from the simulator's own object mesh (ground truth, {why}), not perceived]"
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

    config_dir = str(Path(__file__).resolve().parents[3] / "configs" / "robot")
    outcome: dict[str, bool] = {}

    @hydra.main(version_base="1.3", config_path=config_dir, config_name="mujoco_pick_place")
    @hydra_task(PROG)
    def _main(dcfg: DictConfig) -> None:
        d = OmegaConf.to_container(dcfg, resolve=True)
        if not d.get("out_dir"):
            d["out_dir"] = HydraConfig.get().runtime.output_dir
        res = run_mujoco_pick_place(MujocoPickPlaceConfig.from_dict(d))
        outcome["success"] = bool(res.success)
        print(f"[{'OK' if res.success else 'FAILED'}] {res.message}")
        print(f"log: {res.log_path}\ngif: {res.gif_path}\nmp4: {res.mp4_path}\nstrip: {res.strip_path}")
        print(f"wall time {res.wall_time:.1f} s, {res.num_presses} EIP presses, {len(res.log.get('step', []))} frames")
        announce(d["out_dir"])  # the run's folder, the last line as every CLI's

    _main()
    if outcome.get("success") is False:  # scripts must tell a failed run from a done one (outputs are written)
        sys.exit(1)


def main() -> None:
    """Console entry point (Hydra): ``python -m tvrecon.robot.mujoco.pick_place object=can``; exit 1 on [FAILED].

    Bad input (``place_xy=[0.5]``, ``MUJOCO_GL=bogus``, a missing mesh) is one line on stderr and exit status 2,
    Ctrl-C 130 (``tvrecon.utils.cli_errors``; ``--debug`` keeps the traceback).
    """
    run_hydra_cli(_hydra_entry, prog=PROG)


if __name__ == "__main__":
    main()
