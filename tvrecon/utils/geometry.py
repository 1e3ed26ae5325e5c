"""Geometry helpers shared by the simulator, the data pipeline, the models and the robot demo.

One owner each for: the input check of a triangle mesh (`check_mesh`), reading a user's mesh file with errors that
name the file (`read_mesh_file`), two unit vectors perpendicular to a
direction (`perpendicular_basis`), and the world -> camera transform of the OpenCV convention (`world_to_camera`
for points, `rotate_to_camera` for directions and normals; ``RT = [R | t]`` maps world to camera, x_cam = R x + t).
The module depends on no other part of ``tvrecon``, so every layer may import it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import trimesh
from kornia.geometry.linalg import transform_points
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["check_mesh", "read_mesh_file", "perpendicular_basis", "rt_to_matrix", "world_to_camera", "rotate_to_camera"]


def check_mesh(mesh: trimesh.Trimesh, what: str = "mesh", require_area: bool = False) -> None:
    """Raise ValueError unless ``mesh`` is a non-empty trimesh with finite vertices.

    Args:
        mesh: the mesh to check (V vertices, F faces).
        what: how the error names the mesh (e.g. ``"object mesh"``).
        require_area: also reject a mesh whose faces are all degenerate (zero total area).
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"{what} must be a trimesh.Trimesh (load files with trimesh.load), got {type(mesh).__name__}")
    n_vertices, n_faces = len(mesh.vertices), len(mesh.faces)
    if n_vertices == 0 or n_faces == 0:
        size = f"{n_vertices} vertices, {n_faces} faces"
        raise ValueError(f"{what} has no faces ({size}): pass a non-empty triangle mesh")
    if require_area and not mesh.area > 0:
        raise ValueError(f"{what} has zero surface area ({n_faces} degenerate faces): pass a non-empty triangle mesh")
    if not np.isfinite(np.asarray(mesh.vertices)).all():
        raise ValueError(f"{what} has NaN or infinite vertex coordinates: clean the mesh (e.g. drop those vertices)")


def read_mesh_file(path: str | Path, what: str = "mesh file") -> trimesh.Trimesh:
    """Load a triangle mesh file (.obj, .stl, .ply, .glb, .off, ...) or raise ValueError naming the file.

    trimesh's readers fail in many ways on a bad file (garbage bytes end in "No module named 'charset_normalizer'",
    which sends users to install packages), and its processing silently drops NaN vertices (leaving a hole):
    here any reader failure says the file is not a readable mesh, the raw vertices are checked for NaN / inf, and
    a file without triangles is named.

    Returns:
        The processed trimesh (V vertices, F faces), in the file's own units.
    Raises:
        ValueError: the file is missing, unreadable, holds no triangles or has non-finite vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{what} {str(path)!r} does not exist: pass the path of an existing mesh file")
    no_triangles = (
        f"{what} {str(path)!r} is not a mesh, or is truncated: no triangle could be read from its "
        f"{path.stat().st_size} bytes; pass a complete triangle mesh file (obj, stl, ply, glb, off)"
    )
    raw = _load(path, what, process=False)
    if not isinstance(raw, trimesh.Trimesh) or len(raw.faces) == 0:
        raise ValueError(no_triangles)
    if not np.isfinite(np.asarray(raw.vertices)).all():
        raise ValueError(
            f"{what} {str(path)!r} has NaN or infinite vertex coordinates: clean the mesh (e.g. drop those vertices)"
        )
    mesh = _load(path, what, process=True)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(no_triangles)
    return mesh


def _load(path: Path, what: str, process: bool) -> trimesh.Trimesh | trimesh.Scene:
    try:
        return trimesh.load(path, force="mesh", process=process)
    except Exception as err:  # trimesh's readers fail in many ways (e.g. an ImportError of an optional decoder)
        raise ValueError(
            f"{what} {str(path)!r} is not a mesh, or is truncated (the reader failed: {type(err).__name__}: {err}); "
            f"pass a complete mesh file (.obj, .stl, .ply, .glb, .off), e.g. re-exported from a mesh tool"
        ) from err


_X, _Y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def perpendicular_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to unit direction(s) ``d``: ``e1 = d x a / |d x a|``, ``e2 = d x e1``.

    The helper axis ``a`` is world x, or world y where ``|d_x| >= 0.9``; ``(e1, e2, d)`` is right-handed. The pad
    frame (`tvrecon.sim.sensor.elastic_pad.sensor_frame`) chooses its axis the same way but projects it onto the contact
    plane in float32 torch (its e_x equals ``-e2`` of the press direction up to rounding); it keeps its own code because
    its rounding decides the pad's in-plane orientation in the cached data.

    Args:
        d: (3,) or (N, 3) float64 unit directions (not normalized here: e2 has the length of d).

    Returns:
        e1, e2: each shaped like ``d``, float64.
    """
    d = np.asarray(d, dtype=np.float64)
    a = np.where(np.abs(d[..., :1]) < 0.9, _X, _Y)
    e1 = np.cross(d, a)
    # one direction uses numpy's dot-based 1-D norm, as the voxel carver always has (same bits as before)
    e1 /= np.linalg.norm(e1) if e1.ndim == 1 else np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(d, e1)


def rt_to_matrix(RT: Tensor) -> Tensor:
    """Pad world->camera extrinsics to homogeneous 4x4 matrices.

    Args:
        RT: (B, 3, 4) float ``[R | t]``.

    Returns:
        (B, 4, 4) float, last row ``(0, 0, 0, 1)``.
    """
    check_shape(RT, "(B, 3, 4)", "RT")
    bottom = torch.zeros(RT.shape[0], 1, 4, dtype=RT.dtype, device=RT.device)
    bottom[:, 0, 3] = 1.0
    return torch.cat([RT, bottom], dim=1)


def world_to_camera(points: Tensor, RT: Tensor) -> Tensor:
    """Map world points to the camera frame, ``x_cam = R x + t``, with kornia.

    Args:
        points: (B, N, 3) or (N, 3) world coordinates (tensor or array; integer points become float32).
        RT: (B, 3, 4) or, with unbatched points, (3, 4) world->camera ``[R | t]``; used in the points' dtype and
            on their device.

    Returns:
        Camera coordinates shaped like ``points`` (z = depth, > 0 in front of the camera).
    """
    points = torch.as_tensor(points)
    if not points.is_floating_point():
        points = points.float()
    RT = torch.as_tensor(RT).to(device=points.device, dtype=points.dtype)
    check_shape(points, "(B, N, 3) or (N, 3)", "points")
    if points.dim() == 2:
        check_shape(RT, "(3, 4)", "RT")
        return world_to_camera(points[None], RT[None])[0]
    check_shape(RT, "(B, 3, 4)", "RT")
    if RT.shape[0] != points.shape[0]:
        raise ValueError(f"RT must have shape (B, 3, 4) with B={points.shape[0]}, got {tuple(RT.shape)}")
    with torch.autocast(points.device.type, enabled=False):  # camera geometry stays in the points' precision
        return transform_points(rt_to_matrix(RT), points)


def rotate_to_camera(vectors: Tensor, RT: Tensor) -> Tensor:
    """Rotate world directions or normals into the camera frame, ``R v`` (no translation).

    Args:
        vectors: (B, N, 3) float world vectors.
        RT: (B, 3, 4) float world->camera ``[R | t]``.

    Returns:
        (B, N, 3) camera-frame vectors.
    """
    with torch.autocast(vectors.device.type, enabled=False):  # camera geometry stays in the vectors' precision
        return vectors @ RT[:, :, :3].to(vectors.dtype).transpose(1, 2)
