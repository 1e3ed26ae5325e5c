"""Class registry and :func:`make_shape`, the entry point to every procedural object family."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh

from tvrecon.data.shapes.primitives import finalize

Builder = Callable[[np.random.Generator], "trimesh.Trimesh | list[trimesh.Trimesh]"]

_BUILDERS: dict[str, Builder] = {}

RECON_CLASSES: tuple[str, ...] = (
    "bottle",
    "bowl",
    "can",
    "conditioner",
    "cube",
    "fork",
    "gear",
    "pepsi",
    "spoon",
    "scissors",
)
OTHER_CLASSES: tuple[str, ...] = (
    "mug",
    "torus",
    "banana",
    "wrench",
    "hammer",
    "key",
    "cup",
    "plate",
    "ball",
    "screwdriver",
    "knife",
    "wineglass",
    "dumbbell",
    "pear",
    "egg",
    "bolt",
    "nut",
    "brick",
    "pencil",
    "mushroom",
    "pan",
    "padlock",
    "pawn",
    "star",
    "ladle",
)
CLASSES: tuple[str, ...] = RECON_CLASSES + OTHER_CLASSES


def register(name: str) -> Callable[[Builder], Builder]:
    """Decorator registering ``fn(rng) -> part or list of parts`` as the builder of class ``name``."""

    def deco(fn: Builder) -> Builder:
        if name in _BUILDERS:
            raise ValueError(f"shape class {name!r} registered twice")
        _BUILDERS[name] = fn
        return fn

    return deco


def available_classes() -> tuple[str, ...]:
    """Names of the classes that have a builder, in :data:`CLASSES` order."""
    return tuple(c for c in CLASSES if c in _BUILDERS)


def make_shape(name: str, seed: int = 0) -> trimesh.Trimesh:
    """Build one instance of procedural class ``name`` with parameters drawn from ``seed``.

    Returns a watertight trimesh with positive volume, its bounding-box centre at the origin and its largest extent
    equal to 1.0 (it fits in [-0.5, 0.5]^3). The same (name, seed) always gives the same vertices.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown shape class {name!r}; expected one of {', '.join(available_classes())}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    rng = np.random.default_rng([int(seed), CLASSES.index(name)])
    return finalize(_BUILDERS[name](rng), name=name)
