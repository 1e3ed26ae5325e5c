"""Start a run from another run's weights, and keep chosen parts of the model fixed while it trains.

``train.py init_from=<ckpt>`` loads every parameter and buffer of that Lightning checkpoint whose name and shape the
new model shares (:func:`load_initial_weights`); what the new model has beyond it keeps its initialisation and is
listed in the log. This is a warm start, not a resume (``ckpt_path``): epoch, optimizer and schedule begin afresh.
``freeze=[prefix, ...]`` (:class:`FreezeParameters`) keeps the parameters under those name prefixes fixed and the
modules under them in eval mode, so their BatchNorm statistics stay those of the checkpoint too.

Example: touch geometry's deformer trained on a trained, fixed Pixel2Mesh (the cascade's visual path has the
visual-only model's parameter names)::

    python train.py experiment=touch_cascade data=paper_cpu \
        init_from=logs/<visual_only run>/checkpoints/epoch_007.ckpt 'freeze=[net.visual,net.deformer.stages]'
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import lightning as L
from lightning.pytorch.callbacks import BaseFinetuning
from torch import nn

from tvrecon.utils.checkpoint import load_checkpoint

__all__ = ["FreezeParameters", "WarmStart", "load_initial_weights", "modules_under"]

log = logging.getLogger(__name__)


@dataclass
class WarmStart:
    """What :func:`load_initial_weights` did: entry names loaded, and the model's names the checkpoint lacked / the
    checkpoint's names the model lacks."""

    loaded: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)


def _prefixes(names: Sequence[str]) -> list[str]:
    """The distinct three-part name prefixes of ``names`` (``net.deformer.touch_stages.0.w`` -> its first three)."""
    return sorted({".".join(n.split(".")[:3]) for n in names})


def load_initial_weights(model: nn.Module, ckpt: str | Path) -> WarmStart:
    """Copy the entries of checkpoint ``ckpt`` that ``model`` shares (same name, same shape) into ``model``.

    Args:
        model: the freshly built LightningModule (its ``state_dict`` names, e.g. ``net.visual.stem.0.weight``).
        ckpt: a Lightning checkpoint (checked first: a truncated file is named).

    Returns:
        The names loaded, missing from the checkpoint (left at their initialisation) and unused.

    Raises:
        FileNotFoundError / CorruptCheckpointError: ``ckpt`` is absent or unreadable.
        ValueError: an entry has another shape in the checkpoint (another model size), or the checkpoint shares no
            entry with the model (another kind of model).
    """
    state = load_checkpoint(ckpt)["state_dict"]
    own = model.state_dict()
    clash = [
        f"{k} {tuple(state[k].shape)} vs {tuple(v.shape)}"
        for k, v in own.items()
        if k in state and state[k].shape != v.shape
    ]
    if clash:
        raise ValueError(
            f"init_from={ckpt}: {len(clash)} entries have another shape in the checkpoint than in this model, e.g. "
            f"{clash[0]} (checkpoint vs model): it was trained with another model size; build this model with the "
            f"checkpoint's sizes or start from scratch (init_from=null)"
        )
    shared = [k for k in own if k in state]
    if not shared:
        raise ValueError(
            f"init_from={ckpt} shares no parameter name with this model (it has {_prefixes(list(state))[:4]}, the "
            f"model {_prefixes(list(own))[:4]}): it is a checkpoint of another kind of model"
        )
    model.load_state_dict({k: state[k] for k in shared}, strict=False)
    report = WarmStart(shared, [k for k in own if k not in state], [k for k in state if k not in own])
    log.info(
        "init_from=%s: %d of the model's %d entries loaded; %d kept their initialisation (%s); %d of the checkpoint "
        "unused (%s)",
        ckpt,
        len(report.loaded),
        len(own),
        len(report.missing),
        ", ".join(_prefixes(report.missing)) or "none",
        len(report.unexpected),
        ", ".join(_prefixes(report.unexpected)) or "none",
    )
    return report


def modules_under(model: nn.Module, prefixes: Sequence[str]) -> list[nn.Module]:
    """The submodules of ``model`` named by ``prefixes`` (``net.visual`` -> ``model.net.visual``).

    Raises:
        ValueError: a prefix names no submodule (lists the top-level names to choose from).
    """
    named = dict(model.named_modules())
    unknown = [p for p in prefixes if p not in named]
    if unknown:
        choices = sorted({".".join(n.split(".")[:2]) for n in named if n.count(".") >= 1})
        raise ValueError(f"freeze: {unknown} name no module of the model; modules look like {choices[:8]}")
    return [named[p] for p in prefixes]


class FreezeParameters(BaseFinetuning):
    """Keep the modules under ``prefixes`` fixed for the whole fit: no gradient, eval mode (BatchNorm statistics and
    dropout as in the checkpoint), never unfrozen.

    Lightning puts the whole model in train mode at the start of fitting and may at each epoch; the frozen modules are
    put back in eval mode before every training batch.

    Args:
        prefixes: module names, e.g. ``["net.visual", "net.deformer.stages"]``.
    """

    def __init__(self, prefixes: Sequence[str]) -> None:
        super().__init__()
        if not prefixes:
            raise ValueError("FreezeParameters needs at least one module name")
        self.prefixes = [str(p) for p in prefixes]
        self._frozen: list[nn.Module] = []

    def freeze_before_training(self, pl_module: L.LightningModule) -> None:
        self._frozen = modules_under(pl_module, self.prefixes)
        self.freeze(self._frozen, train_bn=False)
        fixed = sum(p.numel() for m in self._frozen for p in m.parameters())
        total = sum(p.numel() for p in pl_module.parameters())
        log.info("freeze=%s: %d of %d parameters fixed", self.prefixes, fixed, total)
        if not any(p.requires_grad for p in pl_module.parameters()):
            raise ValueError(
                f"freeze={self.prefixes} fixes all {total} parameters of the model: nothing would train. Freeze a "
                f"part of it (e.g. freeze=[net.visual]), or test the weights as they are with eval.py"
            )

    def finetune_function(self, pl_module: L.LightningModule, epoch: int, optimizer: object) -> None:
        """Nothing is unfrozen."""

    def on_train_batch_start(
        self, trainer: L.Trainer, pl_module: L.LightningModule, batch: object, batch_idx: int
    ) -> None:
        for module in self._frozen:
            module.eval()
