"""ObjectLibrary: disjoint splits, determinism, cache-key params, user meshes (good, repaired, broken)."""

from __future__ import annotations

import logging
import pickle
from pathlib import Path

import numpy as np
import pytest
import trimesh

from tvrecon.data.shapes import CLASSES, ObjectLibrary, make_shape


def _check_unit(mesh: trimesh.Trimesh) -> None:
    assert mesh.is_watertight and mesh.volume > 0
    lo, hi = mesh.bounds
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    assert abs(float(np.max(hi - lo)) - 1.0) < 1e-6


def test_default_classes_and_labels() -> None:
    lib = ObjectLibrary(deform=0.0)
    assert lib.classes == list(CLASSES) and len(lib) == 35
    assert lib.label("gear") == CLASSES.index("gear") and lib.label(3) == 3


def test_train_test_never_share_instances() -> None:
    lib = ObjectLibrary(classes=["cube", "torus"], deform=0.1)
    for cls in lib.classes:
        seeds = {s: {lib.params(cls, i, s)["seed"] for i in range(200)} for s in ("train", "val", "test")}
        assert not seeds["train"] & seeds["test"]
        assert not seeds["train"] & seeds["val"] and not seeds["val"] & seeds["test"]
    a, b = lib.get("torus", 0, "train"), lib.get("torus", 0, "test")
    assert a.vertices.shape != b.vertices.shape or not np.allclose(a.vertices, b.vertices)


def test_get_is_normalized_deterministic_and_deformed() -> None:
    lib1 = ObjectLibrary(classes=["mug", "fork"], deform=0.1, seed=4)
    lib2 = ObjectLibrary(classes=["mug", "fork"], deform=0.1, seed=4)
    for cls in ("mug", 1):
        m = lib1.get(cls, 2, "train")
        _check_unit(m)
        np.testing.assert_array_equal(m.vertices, lib2.get(cls, 2, "train").vertices)
    p = lib1.params("mug", 2, "train")
    raw = make_shape("mug", p["seed"])  # the deformation changed the procedural mesh
    assert raw.vertices.shape != lib1.get("mug", 2).vertices.shape or not np.allclose(
        raw.vertices, lib1.get("mug", 2).vertices
    )
    assert ObjectLibrary(classes=["mug"], deform=0.1, seed=5).params("mug", 2)["seed"] != p["seed"]
    # cached copies: mutating a returned mesh does not corrupt the library
    m = lib1.get("fork", 0)
    m.apply_translation([1.0, 0.0, 0.0])
    _check_unit(lib1.get("fork", 0))


def test_params_are_cache_keys() -> None:
    lib = ObjectLibrary(classes=["gear"], deform=0.05)
    p = lib.params("gear", 7, "test")
    assert p["class"] == "gear" and p["split"] == "test" and p["source"] == "procedural"
    assert p["deform"] == 0.05 and {"seed", "version", "instance"} <= set(p)
    assert p != ObjectLibrary(classes=["gear"], deform=0.1).params("gear", 7, "test")
    assert p != lib.params("gear", 8, "test")


def test_library_is_picklable() -> None:
    lib = ObjectLibrary(classes=["egg"], deform=0.1)
    lib.get("egg", 0)
    clone = pickle.loads(pickle.dumps(lib))
    np.testing.assert_array_equal(clone.get("egg", 0).vertices, lib.get("egg", 0).vertices)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda lib: lib.get("teapot", 0), "unknown class 'teapot'"),
        (lambda lib: lib.get(5, 0), r"class index 5 out of range \[0, 2\)"),
        (lambda lib: lib.get("cube", -1), "instance must be a non-negative int"),
        (lambda lib: lib.get("cube", 0, "dev"), "split must be one of"),
    ],
)
def test_bad_requests(call, match: str) -> None:
    lib = ObjectLibrary(classes=["cube", "ball"], deform=0.0)
    with pytest.raises(ValueError, match=match):
        call(lib)


def test_bad_construction() -> None:
    with pytest.raises(ValueError, match="unknown classes"):
        ObjectLibrary(classes=["cube", "spaceship"])
    with pytest.raises(ValueError, match="deform must be"):
        ObjectLibrary(deform=2.0)
    with pytest.raises(ValueError, match="is not a directory"):
        ObjectLibrary(user_root="/nonexistent/meshes")


def _user_folder(root: Path) -> dict[str, Path]:
    (root / "blob").mkdir(parents=True)
    (root / "mug").mkdir()
    files = {
        "good": root / "blob" / "a_good.stl",
        "holed": root / "blob" / "b_holed.obj",
        "open": root / "blob" / "c_open.ply",
        "broken": root / "blob" / "d_broken.ply",
        "glb": root / "blob" / "e_capsule.glb",
        "mug": root / "mug" / "my_mug.obj",
    }
    trimesh.creation.icosphere(subdivisions=2, radius=3.0).export(files["good"])
    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    box.update_faces(np.arange(1, len(box.faces)))  # one missing triangle: fill_holes repairs it
    box.export(files["holed"])
    sph = trimesh.creation.icosphere(subdivisions=3)
    sph.update_faces(sph.triangles_center[:, 2] < 0.6)  # a whole cap missing: needs the voxel remesh
    sph.remove_unreferenced_vertices()
    sph.export(files["open"])
    files["broken"].write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    trimesh.creation.capsule(height=2.0, radius=0.5).export(files["glb"])
    trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=1.5).export(files["mug"])
    return files


def test_user_meshes_good_repaired_broken(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    files = _user_folder(tmp_path / "meshes")
    with caplog.at_level(logging.WARNING):
        lib = ObjectLibrary(user_root=tmp_path / "meshes", deform=0.0)
    # broken file reported by name and skipped; the open ones reported and repaired
    assert files["broken"].name in caplog.text
    assert files["broken"] in lib.report.skipped
    assert files["holed"].name in caplog.text and files["open"].name in caplog.text
    assert set(lib.report.repaired) == {files["holed"], files["open"]}
    assert set(lib.report.loaded) == {files[k] for k in ("good", "holed", "open", "glb", "mug")}
    # "blob" is a new class after the procedural ones; "mug" replaces the procedural mug in place
    assert lib.classes[:35] == list(CLASSES) and lib.classes[35:] == ["blob"]
    assert lib.params("mug", 0)["source"] == "user"
    assert lib.params("mug", 0)["path"] == str(files["mug"])
    seen = set()
    for split in ("train", "test"):
        for i in range(4):
            p = lib.params("blob", i, split)
            assert p["source"] == "user" and len(p["sha256"]) == 64
            seen.add((split, p["path"]))
            _check_unit(lib.get("blob", i, split))
    train = {path for s, path in seen if s == "train"}
    test = {path for s, path in seen if s == "test"}
    assert train and test and not train & test  # user files are split too
    _check_unit(lib.get("mug", 0))


def test_user_only_classes_with_deformation(tmp_path: Path) -> None:
    _user_folder(tmp_path / "m")
    lib = ObjectLibrary(classes=["blob"], user_root=tmp_path / "m", deform=0.1)
    assert lib.classes == ["blob"]
    a, b = lib.get("blob", 0, "train"), lib.get("blob", 3, "train")
    _check_unit(a)
    _check_unit(b)
    p = lib.params("blob", 0)
    assert p["deform"] == 0.1 and p["sha256"]
