"""Data presets: the paper's Table 1 split sizes and the Hydra configs ``configs/data/<preset>.yaml``.

The YAML files are the source of truth for training (``python train.py data=small``). A preset is a defaults list
of blocks in config groups under ``configs/data/``: ``base/`` (datamodule settings: ``recon`` or ``cls`` on top of
``common``), ``sensor/``, ``press/``, ``render/`` (``tiny``, ``small``, ``paper``) and ``touch/`` (the touch policy,
``cone``), plus its own split sizes and resolutions; one block can be swapped from the command line
(``data/sensor=paper``, or ``sensor=paper`` with :func:`compose_preset`). This module holds the
paper's numbers, counts what a datamodule config generates (:func:`split_sizes`) so tests can check that
``paper.yaml`` / ``cls_paper.yaml`` / ``cls_paper_cpu.yaml`` reproduce Table 1, and composes a preset by name
(:func:`compose_preset`) for the ``generate`` CLI.

Presets (reconstruction ``<name>.yaml``, classification ``cls_<name>.yaml``):

- ``paper``: Table 1 (classification 35 classes, 5,500 train / 1,500 test tactile images; reconstruction 35 classes
  6,500 tactile / 650 visual train, 10 classes 500 tactile / 50 visual test), 224 x 224 images and tactile maps,
  64 x 64 sensor pad on a 128^3 grid.
- ``small``: a CPU-sized version (10 reconstruction classes, lower sensor and image resolution) that generates in
  about 10 to 20 minutes and trains in about an hour on 2 cores.
- ``paper_cpu``: the reconstruction split sizes of Table 1 (train all 35 classes, 650 views / 6,500 tactile images;
  test the 10 reconstruction classes, 50 / 500) on ``small``'s pad, grid and views, for Table 3 at the paper's
  data size on 2 CPU cores (about 8 minutes to generate).
- ``cls_paper_cpu``: the classification split sizes of Table 1 (5,500 / 1,500 images, plus 700 validation) with a
  32 x 32 pad on a 64^3 grid (the paper's touch geometry at half its resolution) and 32 px tactile maps, so that
  2 CPU cores generate it in about 15 minutes (``configs/data/cls_paper_cpu.yaml`` says why each value was chosen,
  ``docs/notes/classification.md`` how it was measured).
- ``tiny``: a few objects of 3 classes with a 16 x 16 pad on a 64^3 grid and 64 px views, for tests and the smoke
  experiment.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

__all__ = [
    "SplitSize",
    "TABLE1",
    "PRESETS",
    "CONFIG_DIR",
    "PROJECT_ROOT",
    "split_sizes",
    "compose_preset",
    "preset_names",
    "default_cache_dir",
]

#: The repository (the package is installed in editable mode next to ``configs/``, ``train.py`` and ``data/``).
PROJECT_ROOT = Path(__file__).resolve().parents[2]
#: ``configs/data`` of the repository.
CONFIG_DIR = PROJECT_ROOT / "configs" / "data"

PRESETS = ("tiny", "small", "paper")


@dataclass(frozen=True)
class SplitSize:
    """Size of one split: number of classes, tactile images and visual views."""

    classes: int
    tactile: int
    visual: int


#: Paper Table 1 (train and test splits of both tasks).
TABLE1: dict[str, dict[str, SplitSize]] = {
    "classification": {"train": SplitSize(35, 5500, 0), "test": SplitSize(35, 1500, 0)},
    "reconstruction": {"train": SplitSize(35, 6500, 650), "test": SplitSize(10, 500, 50)},
}


def preset_names() -> list[str]:
    """Names of the YAML presets present in :data:`CONFIG_DIR` (e.g. ``tiny``, ``cls_small``; the blocks in its
    sub-folders are not presets)."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def _get(cfg: Mapping[str, Any], key: str, default: Any = None) -> Any:
    value = cfg.get(key, default)
    return default if value is None else value


def split_sizes(cfg: Mapping[str, Any] | DictConfig, num_library_classes: int = 35) -> dict[str, SplitSize]:
    """What a datamodule config generates per split (``train``, ``val``, ``test``).

    Reconstruction (``_target_`` ends with ``ReconstructionDataModule``): each sample is one view with
    ``max_touches`` cached touches. Classification: each object has ``touches_per_object`` touches.
    ``classes: null`` in a split means all ``num_library_classes`` classes.
    """
    if isinstance(cfg, DictConfig):
        cfg = OmegaConf.to_container(cfg, resolve=True)  # type: ignore[assignment]
    target = str(cfg.get("_target_", ""))
    if target.endswith("ReconstructionDataModule"):
        per_item, visual = int(_get(cfg, "max_touches", 10)), True
        count_key = "num_samples"
    elif target.endswith("ClassificationDataModule"):
        per_item, visual = int(_get(cfg, "touches_per_object", 10)), False
        count_key = "num_objects"
    else:
        raise ValueError(f"config _target_ must be a Reconstruction/ClassificationDataModule, got {target!r}")
    out = {}
    for name in ("train", "val", "test"):
        split = cfg.get(name)
        if not split:
            continue
        n = int(split[count_key])
        classes: Sequence[str] | None = split.get("classes")
        n_cls = num_library_classes if classes is None else len(classes)
        out[name] = SplitSize(min(n_cls, n), n * per_item, n if visual else 0)
    return out


def default_cache_dir() -> Path:
    """The cache ``train.py`` reads by default: ``$PROJECT_ROOT/data/cache``, absolute.

    ``PROJECT_ROOT`` defaults to the repository holding this package (train.py and eval.py set it to their own
    folder, the same one), never to the working directory.
    """
    return Path(os.environ.get("PROJECT_ROOT") or PROJECT_ROOT).resolve() / "data" / "cache"


def _unknown_key(message: str, cfg: DictConfig) -> str | None:
    """For Hydra's "Could not override 'a.b'": a message naming the key and the keys its parent has, else None."""
    import re

    found = re.search(r"Could not override '([^']+)'", message)
    if found is None:
        return None
    key = found.group(1)
    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if not isinstance(node, DictConfig):
        return None
    where = f"'{parent}'" if parent else "the preset"
    return f"unknown data key {key!r}: check its spelling ({where} has {sorted(str(k) for k in node.keys())})"


def compose_preset(name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """Compose ``configs/data/<name>.yaml`` with Hydra command-line style ``overrides`` (``key=value``).

    Without a ``cache_dir=`` override the preset's cache is :func:`default_cache_dir` (absolute), whatever the
    working directory: the YAML's ``${oc.env:PROJECT_ROOT,.}`` fallback would otherwise fill ``./data/cache`` of the
    folder the command was started from, not the cache ``train.py`` reads.
    """
    from hydra import compose, initialize_config_dir

    if not (CONFIG_DIR / f"{name}.yaml").is_file():
        raise ValueError(f"unknown data preset {name!r}; available: {preset_names()} (in {CONFIG_DIR})")
    from hydra.errors import ConfigCompositionException

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        try:
            cfg = compose(config_name=name, overrides=list(overrides))
        except ConfigCompositionException as err:
            # Hydra suggests `+key=value` for a mistyped key, and following that hint ends in a TypeError of the
            # dataset: name the key and list the ones that exist instead
            unknown = _unknown_key(str(err), compose(config_name=name))
            if unknown is None:
                raise
            raise ValueError(unknown) from err
    raw = OmegaConf.to_container(cfg, resolve=False).get("cache_dir")  # type: ignore[union-attr]
    if isinstance(raw, str) and "PROJECT_ROOT" in raw:  # the preset's default, not the user's cache_dir=...
        cfg.cache_dir = str(default_cache_dir())
    return cfg
