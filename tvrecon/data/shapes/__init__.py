"""Procedural object library: 35 parametric classes, seeded deformation, user meshes.

Public API::

    CLASSES, RECON_CLASSES                      # class names (RECON_CLASSES first in CLASSES)
    make_shape(name, seed=0) -> Trimesh         # watertight, bbox-centred at 0, max extent 1.0
    deform_mesh(mesh, seed, strength=0.1)       # smooth seeded volume-preserving deformation
    ObjectLibrary(classes, user_root, deform)   # .get(cls, instance, split), .params(...)

``python -m tvrecon.data.shapes --out DIR`` writes a contact sheet of every class.
"""

from tvrecon.data.shapes import household, recon, solids, tools  # noqa: F401  (registers the builders)
from tvrecon.data.shapes.deform import deform_mesh
from tvrecon.data.shapes.library import SPLITS, ObjectLibrary
from tvrecon.data.shapes.registry import CLASSES, RECON_CLASSES, available_classes, make_shape
from tvrecon.data.shapes.usermeshes import load_user_mesh, scan_user_meshes

__all__ = [
    "CLASSES",
    "RECON_CLASSES",
    "SPLITS",
    "ObjectLibrary",
    "available_classes",
    "deform_mesh",
    "load_user_mesh",
    "make_shape",
    "scan_user_meshes",
]
