"""RGB-D + segmentation from MuJoCo's offscreen renderer, back-projected to world points (headless: MUJOCO_GL=egl).

:func:`open_renderer` raises :class:`RendererUnavailable` with a one-line reason where no OpenGL context can be made
(no EGL, no display), so callers can fall back and say so.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")  # headless offscreen rendering; read when mujoco is imported

#: the MUJOCO_GL values MuJoCo's renderer knows
GL_BACKENDS = ("egl", "osmesa", "glfw", "disable")
#: why the MUJOCO_GL given cannot be used (:func:`check_gl_setting`): importing mujoco with it raised mid-import
BAD_GL_SETTING = ""
if os.environ["MUJOCO_GL"].strip().lower() not in GL_BACKENDS:
    BAD_GL_SETTING = (
        f"MUJOCO_GL={os.environ['MUJOCO_GL']!r} is not a MuJoCo rendering backend: use egl (headless), osmesa "
        f"(software rendering) or glfw (a display), or render=false"
    )
    os.environ["MUJOCO_GL"] = "disable"  # mujoco imports (physics only); the run refuses the setting in one line

_GL_IMPORT_ERROR = ""
try:
    import mujoco
except AttributeError as _err:  # PyOpenGL found no library for the MUJOCO_GL backend (e.g. osmesa not installed)
    _GL_IMPORT_ERROR = f"MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} has no OpenGL library here ({_err})"
    for _name in [n for n in sys.modules if n.split(".")[0] in ("mujoco", "OpenGL")]:
        del sys.modules[_name]  # the failed import left half-built modules behind
    os.environ["MUJOCO_GL"] = "disable"  # physics only; open_renderer says why there are no images
    import mujoco

import numpy as np  # noqa: E402

from tvrecon.utils.shape_check import check_shape  # noqa: E402

__all__ = ["GL_BACKENDS", "RendererUnavailable", "MujocoCamera", "check_gl_setting", "open_renderer", "depth_to_world"]


def check_gl_setting() -> None:
    """Raise ValueError when the user's ``MUJOCO_GL`` names no rendering backend (MuJoCo's own import error was a
    traceback before any message)."""
    if BAD_GL_SETTING:
        raise ValueError(BAD_GL_SETTING)


class RendererUnavailable(RuntimeError):
    """MuJoCo cannot render here (no EGL / display); the message is one line saying why and what to set."""


def open_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` of ``height`` x ``width``; raises :class:`RendererUnavailable` when none can be made."""
    try:
        return mujoco.Renderer(model, height=int(height), width=int(width))
    except Exception as err:  # the GL backends raise several types (RuntimeError, ImportError, mujoco.FatalError)
        backend = os.environ.get("MUJOCO_GL", "")
        reason = _GL_IMPORT_ERROR or " ".join(str(err).split())[:200]
        raise RendererUnavailable(
            f"MuJoCo cannot render (MUJOCO_GL={backend!r}: {reason}); install EGL (libegl1) or run with a display"
        ) from err


def depth_to_world(depth: np.ndarray, cam_pos: np.ndarray, cam_mat: np.ndarray, fovy: float) -> np.ndarray:
    """Back-project a MuJoCo depth image to world points.

    Args:
        depth: (H,W) float depth along the camera's optical axis, metres (``Renderer`` with depth rendering).
        cam_pos: (3,) camera position; cam_mat: (3,3) camera rotation (columns x right, y up, z backwards).
        fovy: vertical field of view, degrees.

    Returns:
        (H,W,3) float64 world coordinates of each pixel.
    """
    depth = np.asarray(depth, dtype=np.float64)
    check_shape(depth, "(H, W)", "depth")
    H, W = depth.shape
    f = 0.5 * H / np.tan(np.deg2rad(fovy) / 2)
    u = (np.arange(W) + 0.5 - W / 2) / f
    v = -(np.arange(H) + 0.5 - H / 2) / f
    x, y = np.meshgrid(u, v)  # (H,W)
    local = np.stack([x * depth, y * depth, -depth], axis=-1)  # (H,W,3) camera frame
    return local @ np.asarray(cam_mat, np.float64).reshape(3, 3).T + np.asarray(cam_pos, np.float64)


class MujocoCamera:
    """A named MJCF camera rendered offscreen: RGB, depth, per-pixel geom ids and world points.

    Args:
        model: the model holding the camera. camera: its name. width, height: image size in pixels.
    """

    def __init__(self, model: mujoco.MjModel, camera: str, width: int = 256, height: int = 256) -> None:
        self.model, self.camera = model, camera
        self.cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if self.cam_id < 0:
            raise ValueError(f"the model has no camera named {camera!r}")
        self.renderer = open_renderer(model, height, width)

    def rgb(self, data: mujoco.MjData) -> np.ndarray:
        """(H,W,3) uint8 colour image."""
        self.renderer.update_scene(data, camera=self.camera)
        return np.asarray(self.renderer.render(), dtype=np.uint8).copy()

    def capture(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Render the scene.

        Returns:
            {"rgb": (H,W,3) uint8, "depth": (H,W) float32 metres along the optical axis,
             "seg": (H,W) int32 geom id per pixel (-1 = background or not a geom), "points": (H,W,3) float32 world}
        """
        r = self.renderer
        rgb = self.rgb(data)
        r.enable_depth_rendering()
        try:
            r.update_scene(data, camera=self.camera)
            depth = np.asarray(r.render(), dtype=np.float64).copy()
        finally:
            r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        try:
            r.update_scene(data, camera=self.camera)
            seg_raw = np.asarray(r.render()).copy()  # (H,W,2): object id, object type
        finally:
            r.disable_segmentation_rendering()
        seg = np.where(seg_raw[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg_raw[..., 0], -1)
        points = depth_to_world(
            depth, data.cam_xpos[self.cam_id], data.cam_xmat[self.cam_id], float(self.model.cam_fovy[self.cam_id])
        )
        return {
            "rgb": rgb,
            "depth": depth.astype(np.float32),
            "seg": seg.astype(np.int32),
            "points": points.astype(np.float32),
        }

    def close(self) -> None:
        """Free the GL context."""
        self.renderer.close()
