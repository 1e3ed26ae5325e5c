"""The one meaning of ``--shape`` (and ``object=``) on every command line: a class of the object library or a mesh file.

``python -m tvrecon.sim press --shape mug``, ``tvrecon.data.preview --shape mug`` and ``--shape my_part.stl`` all go
through :func:`shape_or_mesh_file`: any of the 35 procedural classes (``sphere`` is the library's ``ball``), or a mesh
file read by the one mesh loader (:func:`tvrecon.utils.geometry.read_mesh_file`) and brought to the library's frame
(bounding-box centre at the origin, largest extent 1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from tvrecon.data.shapes.registry import available_classes, make_shape
from tvrecon.utils.geometry import read_mesh_file

__all__ = ["SHAPE_ALIASES", "shape_or_mesh_file", "shape_help"]

#: other names a command line accepts for a library class
SHAPE_ALIASES = {"sphere": "ball"}


def shape_help() -> str:
    """The ``--help`` text of a ``--shape`` option."""
    return f"an object class ({', '.join(available_classes())}; sphere = ball) or a mesh file (.obj, .stl, .ply, ...)"


def shape_or_mesh_file(
    name: str, seed: int = 0, what: str = "--shape", positions: str = "positions"
) -> tuple[trimesh.Trimesh, str | None]:
    """The mesh ``name`` stands for, and a note when a mesh file was moved or scaled (None otherwise).

    Args:
        name: a library class (instance ``seed``), an alias of one, or the path of a mesh file.
        seed: the instance of a library class (ignored for a file).
        what: how errors name the option.
        positions: how the note names the option whose points are in the rescaled units (``--position``).
    Returns:
        ``(mesh, note)``: a watertight library instance, or the file's mesh with its bounding-box centre at the origin
        and its largest extent 1; ``note`` says how a file's coordinates map to the mesh's.
    Raises:
        ValueError: ``name`` is neither a class nor an existing file (the classes are listed), or the file is not a
            mesh, is truncated or has zero size.
    """
    cls = SHAPE_ALIASES.get(str(name), str(name))
    if cls in available_classes():
        return make_shape(cls, seed=seed), None
    path = Path(str(name)).expanduser()
    if not path.is_file():
        raise ValueError(
            f"{what} {name!r} is neither an object class nor an existing mesh file; classes: "
            f"{', '.join(available_classes())} (sphere = ball)"
        )
    mesh = read_mesh_file(path, what=f"{what} file")  # not a mesh / truncated, NaN vertices, no triangles
    extent = float(np.ptp(mesh.bounds, axis=0).max())
    if not extent > 0 or not float(mesh.area) > 0:
        raise ValueError(
            f"{path} has zero size (every triangle is degenerate, largest extent {extent:.3g}): its coordinates were "
            f"probably scaled or rounded to nothing (e.g. a 1e-9 scale written with a few decimals); export it in "
            f"its original units"
        )
    centre = mesh.bounds.mean(0)
    mesh.apply_translation(-centre)
    mesh.apply_scale(1.0 / extent)
    note = None
    if abs(extent - 1.0) > 1e-6 or np.abs(centre).max() > 1e-6:
        note = (
            f"{path.name}: centred at {np.round(centre, 6).tolist()} and scaled by 1/{extent:.6g} to a largest extent "
            f"of 1; {positions} is in these units (a point p of the file is (p - centre) / {extent:.6g})"
        )
    return mesh, note
