"""User meshes: a folder of ``.obj/.stl/.ply/.glb`` files, one subfolder per class.

Every file is loaded, checked and normalized exactly like the procedural shapes (watertight, bounding-box centre at
the origin, largest extent 1.0). Unreadable files are reported by name (logging warning) and skipped; open or
inconsistently wound meshes are reported and repaired (merge, fill holes, fix normals, else a voxel remesh). Nothing
here raises for a bad file: the run goes on with the files that could be used.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from tqdm import tqdm

from tvrecon.data.shapes.primitives import normalize, voxel_remesh
from tvrecon.utils.geometry import read_mesh_file

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb")


@dataclass(frozen=True)
class UserMesh:
    """One usable user mesh: its class, file, content hash and the normalized watertight mesh."""

    cls: str
    path: Path
    sha256: str
    mesh: trimesh.Trimesh = field(repr=False, compare=False)
    repaired: bool = False


@dataclass
class UserMeshReport:
    """What happened to each file: ``loaded`` and ``repaired`` paths, ``skipped`` maps path -> reason."""

    loaded: list[Path] = field(default_factory=list)
    repaired: list[Path] = field(default_factory=list)
    skipped: dict[Path, str] = field(default_factory=dict)


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _read(path: Path) -> trimesh.Trimesh:
    """Read one file as a single Trimesh (scenes are concatenated); raises ValueError when it holds no triangles."""
    loaded = read_mesh_file(path, "user mesh")  # the one mesh loader: not a mesh / truncated, NaN, no triangles
    if float(np.max(loaded.extents)) <= 0:
        raise ValueError("degenerate (zero-size) mesh")
    return loaded


def repair_mesh(mesh: trimesh.Trimesh, name: str = "mesh") -> tuple[trimesh.Trimesh, bool]:
    """Make ``mesh`` a watertight solid with outward normals; returns (mesh, was_repaired).

    Light repairs first (merge vertices, drop degenerate/duplicate faces, fill holes, fix winding and normals);
    if the mesh is still open, a voxel remesh (fill + marching cubes) of the largest part.
    """
    out = mesh.copy()
    out.merge_vertices()
    out.update_faces(out.nondegenerate_faces())
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    if out.is_watertight and out.is_winding_consistent:
        if out.volume < 0:
            out.invert()
        return out, False
    log.warning("user mesh %s is not watertight; repairing", name)
    trimesh.repair.fill_holes(out)
    trimesh.repair.fix_winding(out)
    trimesh.repair.fix_normals(out)
    if not out.is_watertight or out.volume <= 0:
        log.warning("user mesh %s: hole filling was not enough; voxel remesh", name)
        out = voxel_remesh(out)
    if not out.is_watertight or out.volume <= 0:
        raise ValueError("could not be repaired into a watertight solid")
    return out, True


def load_user_mesh(path: str | Path, cls: str | None = None) -> UserMesh:
    """Load, repair and normalize one user mesh file; raises ValueError naming the file if it is unusable."""
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {MESH_SUFFIXES}")
    try:
        mesh = _read(path)
        mesh, repaired = repair_mesh(mesh, name=str(path))
        mesh = normalize(mesh)
    except Exception as err:  # any reader/repair failure is a bad file, reported by name
        raise ValueError(f"{path}: {type(err).__name__}: {err}") from err
    return UserMesh(cls or path.parent.name, path, file_sha256(path), mesh, repaired)


def scan_user_meshes(root: str | Path, progress: bool = True) -> tuple[dict[str, list[UserMesh]], UserMeshReport]:
    """Load every mesh under ``root``/<class>/ (sorted by file name); returns ({class: meshes}, report).

    Broken files are logged with their path and listed in ``report.skipped``; classes left without any usable file
    are omitted. Files directly in ``root`` (no class folder) are skipped with a warning.
    """
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"user mesh root {root} is not a directory; expected <root>/<class>/*.obj|stl|ply|glb")
    report = UserMeshReport()
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
    classes: dict[str, list[UserMesh]] = {}
    for path in tqdm(files, desc="user meshes", unit="file", disable=not progress or len(files) < 10):
        if path.parent == root:
            log.warning("user mesh %s is not inside a class folder; skipped", path)
            report.skipped[path] = "not inside a class folder"
            continue
        cls = path.relative_to(root).parts[0]
        try:
            item = load_user_mesh(path, cls)
        except ValueError as err:
            log.warning("user mesh skipped: %s", err)
            report.skipped[path] = str(err)
            continue
        classes.setdefault(cls, []).append(item)
        report.loaded.append(path)
        if item.repaired:
            report.repaired.append(path)
    return classes, report
