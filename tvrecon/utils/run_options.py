"""Checks of the run options ``train.py`` and ``eval.py`` share, before anything is built.

A value Hydra passes through as typed (``seed=abc`` is the string ``'abc'``) would otherwise fail deep inside torch or
Lightning with a message that names neither the option nor the value (``invalid literal for int()``, ``Invalid
learning rate: -1``, ``set_num_threads expects a positive integer``). Here each is refused with its key and value.
The module depends on no other part of ``tvrecon`` but :mod:`tvrecon.utils.config_utils`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tvrecon.utils.config_utils import check_number, check_whole

__all__ = ["check_optimizer", "check_run_options", "check_trainer_counts"]

#: trainer options that count epochs or steps: whole numbers, -1 meaning "no limit" where Lightning allows it
_TRAINER_COUNTS = ("max_epochs", "min_epochs", "max_steps", "min_steps", "check_val_every_n_epoch",
                   "log_every_n_steps", "accumulate_grad_batches")  # fmt: skip


def check_trainer_counts(trainer: Mapping[str, Any] | None) -> None:
    """Refuse a ``trainer.<count>`` that is not a whole number (``trainer.max_epochs=abc``, ``=2.5``).

    Raises:
        TypeError / ValueError: naming ``trainer.<key>`` and the value given.
    """
    for key in _TRAINER_COUNTS:
        value = (trainer or {}).get(key)
        if value is not None:
            check_whole(value, f"trainer.{key}")  # the range is train.py's check_training_length


def check_optimizer(model: Mapping[str, Any] | None) -> None:
    """Refuse ``model.optimizer.lr`` / ``weight_decay`` that are not numbers, a learning rate <= 0 and a negative
    weight decay (torch's own errors name neither the option nor the config key).

    Raises:
        TypeError / ValueError: naming ``model.optimizer.<key>`` and the value given.
    """
    optimizer = (model or {}).get("optimizer") or {}
    if not isinstance(optimizer, Mapping):
        return
    lr = optimizer.get("lr")
    if lr is not None:
        check_number(lr, "model.optimizer.lr")
        if not float(lr) > 0:
            raise ValueError(f"model.optimizer.lr must be > 0, got {lr!r}")
    wd = optimizer.get("weight_decay")
    if wd is not None:
        check_number(wd, "model.optimizer.weight_decay")
        if not float(wd) >= 0:
            raise ValueError(f"model.optimizer.weight_decay must be >= 0, got {wd!r}")


def check_run_options(cfg: Mapping[str, Any]) -> None:
    """The options of a ``train.py`` / ``eval.py`` config that are read as numbers, each checked with its key.

    ``seed`` a whole number (or null), ``torch_threads`` a whole number >= 1 (or null = torch's default), the
    trainer's epoch and step counts whole numbers, and the optimizer's lr > 0 (train.py).

    Raises:
        TypeError / ValueError: naming the key and the value given.
    """
    if cfg.get("seed") is not None:
        check_whole(cfg.get("seed"), "seed", minimum=0)
    if cfg.get("torch_threads") is not None:
        check_whole(cfg.get("torch_threads"), "torch_threads (null = torch's default)", minimum=1)
    check_trainer_counts(cfg.get("trainer"))
    check_optimizer(cfg.get("model"))
