"""Procedural object library: 35 parametric classes, seeded deformation, user meshes.

Public API::

    CLASSES, RECON_CLASSES            # class names (RECON_CLASSES first in CLASSES)
    make_shape(name, seed=0)          # watertight, centred, max extent 1.0
"""

from tvrecon.data.shapes import household, recon, solids, tools  # noqa: F401  (registers builders)
from tvrecon.data.shapes.registry import CLASSES, RECON_CLASSES, available_classes, make_shape

__all__ = ["CLASSES", "RECON_CLASSES", "available_classes", "make_shape"]
