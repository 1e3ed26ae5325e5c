"""The MuJoCo pick-and-place: the MJCF scene, the RGB-D back-projection, and a short full run (slow)."""

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")
mujoco = pytest.importorskip("mujoco")

from tvrecon.robot.mujoco.camera import RendererUnavailable, depth_to_world  # noqa: E402
from tvrecon.robot.mujoco.pick_place import run_mujoco_pick_place  # noqa: E402
from tvrecon.robot.mujoco.pick_place_config import MujocoPickPlaceConfig  # noqa: E402
from tvrecon.robot.mujoco.scene import MAX_OPENING, MujocoScene, look_at_xyaxes  # noqa: E402
from tvrecon.robot.mujoco.task import yaw_for  # noqa: E402
from tvrecon.robot.pad_config import PadConfig  # noqa: E402
from tvrecon.robot.pick_place_common import resolve_object_mesh  # noqa: E402


def test_the_scene_rests_the_object_on_the_table_with_the_gripper_open() -> None:
    scene = MujocoScene(resolve_object_mesh("cube"))
    pos, _ = scene.object_pose()
    low = scene.object_mesh_world().bounds[0, 2]
    assert abs(low - scene.cfg.table_height) < 2e-3 and np.allclose(pos[:2], scene.cfg.object_xy, atol=2e-3)
    assert np.all(scene.finger_positions() < 2e-3)  # open
    scene.grip(20.0)
    scene.step(300)  # nothing between the fingers: they shut (the pads meet, within the equality's give)
    assert np.all(scene.finger_positions() > MAX_OPENING / 2 - 5e-3)


def test_depth_back_projection_and_camera_axes() -> None:
    xy = look_at_xyaxes(np.array([0.0, 0.0, 1.0]), np.zeros(3), up=(0.0, 1.0, 0.0))
    assert np.allclose(xy, [1, 0, 0, 0, 1, 0])  # looking straight down, image up = world y
    depth = np.full((4, 6), 2.0)
    pts = depth_to_world(depth, np.array([0.0, 0.0, 2.0]), np.eye(3), fovy=90.0)
    assert np.allclose(pts[..., 2], 0.0) and pts.shape == (4, 6, 3)
    assert pts[0, 0, 0] < 0 < pts[0, -1, 0] and pts[0, 0, 1] > 0 > pts[-1, 0, 1]  # x right, y up
    assert np.allclose(np.abs(pts[0, 0, 1]), 2.0 * (1.5 / 2.0), atol=1e-9)  # tan(45 deg) * depth at the pixel centre
    with pytest.raises(ValueError, match=r"depth must have shape \(H, W\), got \(3,\)"):
        depth_to_world(np.zeros(3), np.zeros(3), np.eye(3), 45.0)


def test_yaw_and_objects() -> None:
    for c in ([0.0, 1.0], [1.0, 0.0], [0.6, -0.8], [-0.6, -0.8]):
        yaw = yaw_for(np.array(c))
        y_axis = np.array([-np.sin(yaw), np.cos(yaw)])
        assert abs(abs(y_axis @ np.array(c)) - 1.0) < 1e-9 and abs(yaw) <= np.pi / 2 + 1e-9
    pybullet_data = pytest.importorskip("pybullet_data")
    assert pybullet_data is not None and len(resolve_object_mesh("duck").faces) > 1000


@pytest.mark.slow
def test_a_short_run_picks_and_places_the_cube(tmp_path) -> None:
    cfg = MujocoPickPlaceConfig(
        object="cube",
        out_dir=str(tmp_path),
        pad=PadConfig(resolution=(12, 12), layers=3, n_grid=40),
        render_size=(96, 72),
        lift_height=0.06,
        place_xy=(0.5, 0.0),
        write_gif=False,
        write_mp4=False,
        progress=False,
    )
    try:
        res = run_mujoco_pick_place(cfg)
    except RendererUnavailable as err:  # pragma: no cover - the run itself falls back; this is the camera test
        pytest.skip(str(err))
    assert res.success, res.message
    assert res.placement_error < 0.02
    log = res.log
    contact = log["contact"]
    phases = log["phase"]
    names = list(log["phase_names"])
    held = np.isin(phases, [names.index(p) for p in ("squeeze", "lift", "carry")])
    assert contact[held].all()  # both pads touch while the object is held
    assert log["tactile"][held][:, :, 2].max() > 0.05  # and feel it
    assert not contact[-1].any() and not log["tactile"][-1].any()  # back at rest after the release
    assert res.strip_path is not None and res.strip_path.exists() and res.log_path.exists()
    assert res.num_presses >= 2


@pytest.mark.parametrize("backend", ["disable", "osmesa"])
def test_no_gl_backend_gives_a_one_line_reason(backend: str) -> None:
    """Without a usable OpenGL backend (none, or one whose library is missing) MuJoCo still imports and the renderer
    says why in one line (the demo then plans from the model's geometry)."""
    import subprocess
    import sys

    code = (
        "from tvrecon.robot.mujoco.camera import RendererUnavailable, mujoco, open_renderer\n"
        "m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"0.1\"/></worldbody></mujoco>')\n"
        "try:\n    open_renderer(m, 8, 8)\nexcept RendererUnavailable as err:\n    print('REASON', err)\n"
    )
    env = {**os.environ, "MUJOCO_GL": backend}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    reasons = [line for line in out.stdout.splitlines() if line.startswith("REASON")]
    assert out.returncode == 0, out.stderr[-2000:]
    if backend == "osmesa" and not reasons:  # pragma: no cover - a machine with OSMesa renders
        pytest.skip("OSMesa is installed here")
    assert len(reasons) == 1 and "MuJoCo cannot render" in reasons[0]
