"""The reconstruction training step of an earlier commit, swapped into today's modules, for ``bench_train_step.py``.

``old_step(commit)`` reads the graph deformer (``tvrecon/models/components/gcn.py``), touch geometry's deformation
block and the chamfer (``tvrecon/losses/chamfer.py``) of ``commit`` with ``git show`` into temporary modules and, while
the context is open, makes today's classes run that code: ``GraphConv``, ``GResBlock``, ``DeformationBlock`` and
``MeshDeformer`` (forward and its neighbour cache), touch geometry's block, its per-stage touch features and its patch
term, and the chamfer search of ``tvrecon.losses.mesh``. Parameters, buffers and the backbones are shared, so a module
built today runs the old step on the same weights. The default commit, ``487a852``, is the step before the training
step was made cheaper: every graph conv two matrix products and a sparse product whose backward transposes the
operator, the perceptual features sampled at every vertex and concatenated, the touch features from a (B, V, P, 3)
difference block, the chamfer's broadcast-input search, float32 and contiguous images.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import types
from collections.abc import Iterator
from pathlib import Path

import tvrecon.losses.mesh as mesh_losses
from tvrecon.models.components import gcn, touch_geometry

ROOT = Path(__file__).resolve().parents[2]
BASELINE = "487a852"
# modules renamed after BASELINE that its files import
_RENAMED_MODULES = {"tvrecon.utils.shapes": "tvrecon.utils.shape_check"}

# (module of today, attribute path, module file of the old commit, attribute path there)
_SWAPS = (
    (gcn.GraphConv, "forward", "tvrecon/models/components/gcn.py", ("GraphConv", "forward")),
    (gcn.GResBlock, "forward", "tvrecon/models/components/gcn.py", ("GResBlock", "forward")),
    (gcn.DeformationBlock, "forward", "tvrecon/models/components/gcn.py", ("DeformationBlock", "forward")),
    (gcn.MeshDeformer, "forward", "tvrecon/models/components/gcn.py", ("MeshDeformer", "forward")),
    (gcn.MeshDeformer, "_level_neighbours", "tvrecon/models/components/gcn.py", ("MeshDeformer", "_level_neighbours")),
    (
        touch_geometry.TouchDeformationBlock,
        "forward",
        "tvrecon/models/components/touch_geometry.py",
        ("TouchDeformationBlock", "forward"),
    ),
    (
        touch_geometry.TouchGeometryDeformer,
        "_deform",
        "tvrecon/models/components/touch_geometry.py",
        ("TouchGeometryDeformer", "_deform"),
    ),
    (touch_geometry, "patch_to_mesh_loss", "tvrecon/models/components/touch_geometry.py", ("patch_to_mesh_loss",)),
    (mesh_losses, "chamfer_terms", "tvrecon/losses/chamfer.py", ("chamfer_terms",)),
)


def load_old_module(commit: str, path: str) -> types.ModuleType:
    """The file ``path`` of ``commit`` executed as a fresh module (its imports resolve to today's package).

    Raises ValueError naming the commit when git cannot show the file (not a git checkout, unknown commit).
    """
    try:
        source = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{commit}:{path}"], check=True, capture_output=True, text=True
        ).stdout
    except (OSError, subprocess.CalledProcessError) as err:
        raise ValueError(f"cannot read {path} at commit {commit} with git (run from a git checkout): {err}") from err
    for before, after in _RENAMED_MODULES.items():  # modules renamed since: the old file imports today's
        source = source.replace(f"from {before} import", f"from {after} import")
    name = f"_tvrecon_{commit}_{path.replace('/', '_').removesuffix('.py')}"
    module = types.ModuleType(name)
    module.__file__ = f"{commit}:{path}"
    sys.modules[name] = module  # dataclasses / typing look their module up while the class bodies run
    exec(compile(source, module.__file__, "exec"), module.__dict__)
    return module


@contextlib.contextmanager
def old_step(commit: str = BASELINE) -> Iterator[None]:
    """Run the training step's deformer and losses as at ``commit`` while the context is open (see the module doc).

    Modules keep their parameters; a deformer's cached neighbour operators are per code path, so use separate module
    instances for the two paths (e.g. ``copy.deepcopy`` before the first forward).
    """
    files: dict[str, types.ModuleType] = {}
    saved = []
    try:
        for owner, attr, path, old_attr in _SWAPS:
            if path not in files:
                files[path] = load_old_module(commit, path)
            old = files[path]
            for part in old_attr:
                old = getattr(old, part)
            saved.append((owner, attr, owner.__dict__[attr]))
            setattr(owner, attr, old)
        yield
    finally:
        for owner, attr, value in reversed(saved):
            setattr(owner, attr, value)
