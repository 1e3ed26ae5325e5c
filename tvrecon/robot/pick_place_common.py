"""What the pick-and-place demos of both engines share: the phases they log, the object they pick and the settings
their configurations have in common (:class:`PickPlaceSettings`).

The object is a procedural class of the object library, a ``pybullet_data`` mesh by name (when pybullet is installed)
or any mesh file, scaled to its size and centred on its centre of mass before an engine builds its body.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from tvrecon.robot.pad_config import PadConfig
from tvrecon.utils.geometry import check_mesh, read_mesh_file

__all__ = ["PHASES", "PickPlaceSettings", "load_object_mesh", "prepare_object_mesh", "resolve_object_mesh"]

PHASES = ("approach", "contact", "squeeze", "lift", "carry", "place", "release")


@dataclass
class PickPlaceSettings:
    """The settings both engines' pick-and-place configurations share (each adds its scene, camera and timing).

    object: a procedural class (``tvrecon.data.shapes``), a ``pybullet_data`` mesh name (``duck``) or a mesh path.
    place_xy: (2,) where the object is put down. approach_height / lift_height: metres above the grasp height.
    speed: Cartesian hand speed, m/s. contact_force / grip_force: N per finger while closing / after the squeeze.
    render_size: (W, H) of the scene frames. out_dir: where the GIF, MP4, strip and log go.
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
    render: bool = True
    render_size: tuple[int, int] = (256, 192)
    out_dir: str = "outputs/robot"
    write_gif: bool = True
    write_mp4: bool = True  # needs imageio-ffmpeg ([robot] extra); skipped with a warning when missing
    write_strip: bool = True
    progress: bool = True
    torch_threads: int | None = 1  # small EIP presses run fastest single-threaded; None keeps torch's setting
    pad: PadConfig = field(default_factory=PadConfig)


def prepare_object_mesh(mesh: trimesh.Trimesh, size: float) -> trimesh.Trimesh:
    """Scale a mesh so its longest bounding-box side is ``size`` metres and move its centre of mass to the origin.

    Args:
        mesh: any trimesh (V vertices, F faces); procedural shapes are unit-box normalized, user meshes any scale.
        size: target longest side in metres (> 0).

    Returns:
        A new trimesh in the object's body frame (vertices (V,3) float64 in metres, centre of mass at 0).
    """
    check_mesh(mesh, "object mesh")
    if not size > 0:
        raise ValueError(f"object size must be > 0 metres, got {size}")
    m = mesh.copy()
    extent = float(np.max(m.extents))
    if extent <= 0:
        raise ValueError("object mesh has zero extent: all vertices coincide")
    m.apply_scale(size / extent)
    centre = m.center_mass if m.is_volume else m.bounds.mean(axis=0)
    m.apply_translation(-np.asarray(centre))
    return m


def load_object_mesh(name_or_path: str, seed: int = 0) -> trimesh.Trimesh:
    """A procedural class (``tvrecon.data.shapes.make_shape``) or a mesh file (anything ``trimesh.load`` reads)."""
    path = Path(str(name_or_path)).expanduser()
    mesh_suffix = path.suffix.lower().lstrip(".") in trimesh.available_formats()
    if path.suffix and (path.exists() or os.sep in str(name_or_path) or mesh_suffix):
        if not path.exists():  # `object=mug.obj` is a file name, not an unknown shape class
            raise ValueError(
                f"object mesh file {str(path)!r} does not exist (in {Path.cwd()}): pass an existing mesh path "
                f"or a class name"
            )
        # unreadable bytes and NaN vertices are named here (trimesh would say "charset_normalizer" / drop them)
        return read_mesh_file(path, "object mesh file")
    from tvrecon.data.shapes import make_shape

    return make_shape(str(name_or_path), seed=seed)


def resolve_object_mesh(name_or_path: str, seed: int = 0) -> trimesh.Trimesh:
    """A library class (``make_shape``), a ``pybullet_data`` mesh by name (``duck`` -> ``duck.obj``) or a mesh file."""
    from tvrecon.data.shapes import CLASSES

    name = str(name_or_path)
    if name not in CLASSES and not Path(name).suffix:
        data_dir = _pybullet_data_dir()
        if data_dir is not None and (data_dir / f"{name}.obj").exists():
            return load_object_mesh(str(data_dir / f"{name}.obj"), seed)
    return load_object_mesh(name, seed)


def _pybullet_data_dir() -> Path | None:
    """The folder of the ``pybullet_data`` meshes when pybullet is installed, found without importing pybullet."""
    try:
        spec = importlib.util.find_spec("pybullet_data")
    except (ImportError, ValueError):  # ValueError: a module hidden as sys.modules[name] = None
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))
