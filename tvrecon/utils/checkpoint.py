"""Checkpoint files checked before use: a truncated or corrupt ``.ckpt`` is reported with its path.

torch's own error for a truncated checkpoint ("failed finding central directory") does not name the file, and a
checkpoint whose middle was damaged can even load with wrong weights. Lightning/torch checkpoints are zip archives
with a CRC per member, so :func:`check_checkpoint` verifies the archive (reads it once, no unpickling).
:func:`load_run` is what ``eval.py`` and ``cls_fuse`` read a trained run with: the checked checkpoint and the run's
config, its moved ``_target_`` paths rewritten.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf

from tvrecon.utils.moved_targets import upgrade_targets

__all__ = ["CorruptCheckpointError", "check_checkpoint", "load_checkpoint", "load_run", "run_config_path"]

log = logging.getLogger(__name__)


class CorruptCheckpointError(ValueError):
    """A checkpoint file exists but cannot be read (truncated, damaged, or not a torch checkpoint)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = Path(path)
        super().__init__(
            f"checkpoint {self.path} is truncated or corrupt ({reason}): it was probably written by a run that was "
            f"killed while saving, or copied incompletely; use another checkpoint of the run (e.g. last.ckpt or an "
            f"earlier epoch) or delete this file"
        )


def check_checkpoint(path: str | Path) -> Path:
    """Raise :class:`CorruptCheckpointError` unless ``path`` is a complete torch zip checkpoint. Returns the path.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        CorruptCheckpointError: not a zip archive (truncated files lose the zip's central directory) or a member's
            CRC does not match.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as err:
        if isinstance(err, PermissionError):
            raise
        raise CorruptCheckpointError(path, f"{type(err).__name__}: {err}") from err
    if bad is not None:
        raise CorruptCheckpointError(path, f"member {bad} fails its CRC check")
    return path


def load_checkpoint(path: str | Path, weights_only: bool = True) -> dict[str, Any]:
    """Check then ``torch.load`` a checkpoint on the CPU; any read failure names the file.

    Raises:
        FileNotFoundError / CorruptCheckpointError: as :func:`check_checkpoint`, or torch cannot unpickle it.
    """
    path = check_checkpoint(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=weights_only)
    except (RuntimeError, EOFError, OSError) as err:
        if isinstance(err, PermissionError):
            raise
        raise CorruptCheckpointError(path, f"{type(err).__name__}: {err}") from err
    if not isinstance(state, dict) or "state_dict" not in state:
        raise CorruptCheckpointError(path, "no 'state_dict' in it: not a Lightning checkpoint")
    return state


def run_config_path(ckpt: str | Path) -> Path:
    """The config of the run that wrote ``ckpt``: ``<run>/checkpoints/x.ckpt`` -> ``<run>/.hydra/config.yaml``."""
    return Path(ckpt).resolve().parent.parent / ".hydra" / "config.yaml"


def load_run(ckpt: str | Path, who: str, hint: str) -> tuple[dict[str, Any], DictConfig]:
    """A trained run's checkpoint and config: its state (checked, on the CPU) and its ``.hydra/config.yaml`` with
    the ``_target_`` of modules that have moved since rewritten (:func:`~tvrecon.utils.moved_targets.upgrade_targets`).

    Args:
        ckpt: a checkpoint inside its ``train.py`` run folder.
        who: what is loading it, the start of every message (``eval.py``, ``cls_fuse``).
        hint: what to do when the run's config is missing.

    Raises:
        FileNotFoundError: the run's config does not exist (names it and ``ckpt``).
        CorruptCheckpointError: the checkpoint cannot be read (names the file).
    """
    cfg_path = run_config_path(ckpt)
    if not cfg_path.is_file():
        raise FileNotFoundError(f"{who}: {cfg_path} (the config of the run that wrote {ckpt}) does not exist: {hint}")
    state = load_checkpoint(ckpt)  # plain tensors and hparams only; a corrupt file is named before any work
    run_cfg = OmegaConf.load(cfg_path)
    if not isinstance(run_cfg, DictConfig):
        raise ValueError(f"{who}: {cfg_path} is not a mapping (a train.py run config is)")
    moved = upgrade_targets(run_cfg)  # a run of an earlier layout names modules that have moved since
    if moved:
        log.info(
            f"{cfg_path}: {len(moved)} _target_ of an earlier release rewritten, e.g. {moved[0][0]} -> {moved[0][1]}"
        )
    return state, run_cfg
