"""ObjectLibrary: procedural classes plus optional user meshes, with seeded deformation and disjoint splits."""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from tvrecon.data.shapes.deform import deform_mesh
from tvrecon.data.shapes.primitives import normalize
from tvrecon.data.shapes.registry import CLASSES, available_classes, make_shape
from tvrecon.data.shapes.usermeshes import UserMesh, UserMeshReport, scan_user_meshes

log = logging.getLogger(__name__)

SPLITS: tuple[str, ...] = ("train", "val", "test")
#: How train, val and test objects relate (``ObjectLibrary(protocol=...)``): ``"unseen"`` (every object its own shape:
#: test shapes are never seen in training) or ``"shared_base"`` (the paper's Table 1 caption and section 4.3 read
#: literally: one base mesh per class, every object of every split a random deformation of it).
PROTOCOLS: tuple[str, ...] = ("unseen", "shared_base")
SHAPES_VERSION = 1  # bump when a builder or the deformation changes, so caches keyed on params() are invalidated
_TEST_EVERY = 5  # user meshes: every 5th file of a class (at least one when a class has >= 2 files) is test-only


class ObjectLibrary:
    """Objects for the datasets: ``get(cls, instance, split)`` returns a watertight, unit-box-normalized mesh.

    Procedural instance seeds are ``(seed * 1_000_003 + instance) * 3 + split_index``, so train, val and test never
    share a shape seed. With ``protocol="unseen"`` (default) that seed builds the shape and deforms it, so every object
    is its own shape; with ``protocol="shared_base"`` every object of a class is built from one base seed (the
    seed of train instance 0) and only its deformation follows its own seed: train and test are random deformations
    of one base mesh per class (``deform`` must then be > 0).

    User classes (``user_root/<class>/*.obj|stl|ply|glb``) are added to the procedural ones, or replace the
    procedural class of the same name; their files are split so that test files are never used for
    train or val (a class with a single file is shared by all splits, with a warning: only the deformation differs).

    Args:
        classes: class names to use, in label order (default: every procedural class, then new user classes).
        user_root: optional folder of user meshes, one subfolder per class.
        deform: deformation strength (fraction of the object size, 0 disables; see :func:`deform_mesh`).
        seed: library seed; different seeds give different instances for the same (cls, instance, split).
        protocol: the split protocol, one of :data:`PROTOCOLS` (see above); user classes follow it too (``shared_base``
            uses a class's first file for every split).
        cache_size: number of built meshes kept in memory (LRU).
    """

    def __init__(
        self,
        classes: Sequence[str] | None = None,
        user_root: str | Path | None = None,
        deform: float = 0.1,
        seed: int = 0,
        cache_size: int = 64,
        protocol: str = "unseen",
    ) -> None:
        if not np.isfinite(deform) or not 0.0 <= deform <= 0.5:
            raise ValueError(f"deform must be a strength in [0, 0.5], got {deform}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative int, got {seed!r}")
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
        if protocol == "shared_base" and deform <= 0:
            raise ValueError(
                "protocol='shared_base' makes every object a random deformation of one base mesh per class, so it "
                f"needs deform > 0 (got {deform}): with no deformation train and test objects would be identical"
            )
        self.deform = float(deform)
        self.seed = int(seed)
        self.protocol = str(protocol)
        self.user_root = Path(user_root) if user_root is not None else None
        self.user: dict[str, list[UserMesh]] = {}
        self.report = UserMeshReport()
        if self.user_root is not None:
            self.user, self.report = scan_user_meshes(self.user_root)
        procedural = available_classes()
        if classes is None:
            names = list(procedural) + sorted(c for c in self.user if c not in procedural)
        else:
            names = list(classes)
            unknown = [c for c in names if c not in procedural and c not in self.user]
            if unknown:
                raise ValueError(
                    f"unknown classes {unknown}: expected procedural classes ({', '.join(CLASSES)}) "
                    f"or user classes found under {self.user_root} ({', '.join(sorted(self.user)) or 'none'})"
                )
            if len(set(names)) != len(names):
                raise ValueError(f"classes must be unique, got {names}")
        if not names:
            raise ValueError("ObjectLibrary needs at least one class")
        self.classes: list[str] = names
        for c in names:
            if c in self.user and len(self.user[c]) == 1:
                log.warning("user class %r has a single file: train and test share its base mesh", c)
        self._cache: OrderedDict[tuple[str, int, str], trimesh.Trimesh] = OrderedDict()
        self._cache_size = int(cache_size)

    def __len__(self) -> int:
        return len(self.classes)

    def __repr__(self) -> str:
        n_user = sum(c in self.user for c in self.classes)
        return (
            f"ObjectLibrary({len(self.classes)} classes, {n_user} from user meshes, deform={self.deform}, "
            f"protocol={self.protocol!r})"
        )

    def label(self, cls: str | int) -> int:
        """Integer label (index in ``classes``) of a class name or index."""
        return self.classes.index(self._name(cls))

    def _name(self, cls: str | int) -> str:
        if isinstance(cls, (int, np.integer)) and not isinstance(cls, bool):
            if not 0 <= int(cls) < len(self.classes):
                raise ValueError(f"class index {cls} out of range [0, {len(self.classes)})")
            return self.classes[int(cls)]
        if isinstance(cls, str) and cls in self.classes:
            return cls
        raise ValueError(f"unknown class {cls!r}; expected an index or one of {', '.join(self.classes)}")

    @staticmethod
    def _check(instance: int, split: str) -> None:
        if isinstance(instance, bool) or not isinstance(instance, (int, np.integer)) or instance < 0:
            raise ValueError(f"instance must be a non-negative int, got {instance!r}")
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")

    def _user_files(self, name: str, split: str) -> list[UserMesh]:
        items = self.user[name]
        if self.protocol == "shared_base":
            return items[:1]
        if len(items) < 2:
            return items
        test = [i for i in range(len(items)) if i % _TEST_EVERY == _TEST_EVERY - 1] or [len(items) - 1]
        if split == "test":
            return [items[i] for i in test]
        return [m for i, m in enumerate(items) if i not in test]

    def params(self, cls: str | int, instance: int, split: str = "train") -> dict[str, Any]:
        """Everything that determines ``get(cls, instance, split)`` (JSON-serializable, for cache keys)."""
        name = self._name(cls)
        self._check(instance, split)
        shape_seed = (self.seed * 1_000_003 + int(instance)) * len(SPLITS) + SPLITS.index(split)
        out: dict[str, Any] = {
            "class": name,
            "split": split,
            "instance": int(instance),
            "seed": shape_seed,
            "deform": self.deform,
            "version": SHAPES_VERSION,
        }
        if self.protocol != "unseen":  # out of the key at the default: "unseen" keys are those from before protocols
            out["protocol"] = self.protocol
            out["base_seed"] = self.seed * 1_000_003 * len(SPLITS)  # the shape seed of train instance 0
        if name in self.user:
            item = self._user_files(name, split)[int(instance) % len(self._user_files(name, split))]
            out.update(source="user", path=str(item.path), sha256=item.sha256)
        else:
            out["source"] = "procedural"
        return out

    def get(self, cls: str | int, instance: int, split: str = "train") -> trimesh.Trimesh:
        """Mesh of instance ``instance`` of class ``cls`` in ``split``: watertight, centred, max extent 1.0."""
        p = self.params(cls, instance, split)
        key = (p["class"], p["instance"], p["split"])
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key].copy()
        if p["source"] == "user":
            item = next(m for m in self.user[p["class"]] if str(m.path) == p["path"])
            mesh = item.mesh.copy()
        else:
            mesh = make_shape(p["class"], p.get("base_seed", p["seed"]))
        if self.deform > 0:
            mesh = normalize(deform_mesh(mesh, seed=p["seed"], strength=self.deform))
        self._cache[key] = mesh
        if len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return mesh.copy()
