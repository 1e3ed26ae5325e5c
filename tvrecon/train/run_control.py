"""The run control shared by the entry points ``train.py`` and ``eval.py``: the checkpoint to resume from, a SIGTERM
that exits 143 naming what to do next, the model/data check and the reconstruction test split's touch count.

The run's results (``metrics.json`` and the paper tables) are written by :mod:`tvrecon.report.run_report`.
"""

from __future__ import annotations

import logging
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NoReturn

import lightning as L
from lightning.pytorch.utilities.exceptions import SIGTERMException
from omegaconf import DictConfig, open_dict

__all__ = [
    "check_model_matches_data",
    "exit_on_sigterm",
    "fix_test_touches",
    "last_checkpoint",
]

log = logging.getLogger(__name__)


def last_checkpoint(trainer: L.Trainer) -> Path | None:
    """The newest checkpoint the trainer's ModelCheckpoint wrote (its ``last.ckpt`` when saved), None if none yet."""
    cb = trainer.checkpoint_callback
    if cb is None:
        return None
    for attr in ("last_model_path", "best_model_path"):
        path = getattr(cb, attr, "")
        if path and Path(path).is_file():
            return Path(path)
    dirpath = getattr(cb, "dirpath", None)
    ckpts = sorted(Path(dirpath).glob("*.ckpt"), key=lambda p: p.stat().st_mtime) if dirpath else []
    return ckpts[-1] if ckpts else None


@contextmanager
def exit_on_sigterm(trainer: L.Trainer, stage: str, hint: str | None = None) -> Iterator[None]:
    """Turn Lightning's SIGTERM stop (a ``SystemExit`` with code 0) into exit status 143 and a message.

    Ctrl-C likewise (Lightning exits 1 after its graceful shutdown): exit status 130 = 128 + SIGINT, the same
    message naming the checkpoint to resume from.

    Lightning stops its loops cleanly on SIGTERM but raises ``SIGTERMException``, a ``SystemExit(None)`` that would
    exit 0, so a script or scheduler would take a killed run for a finished one. Here the run says that it was
    terminated, at which epoch/step and what to do next (``hint``; by default the last checkpoint to resume from),
    then exits with 128 + SIGTERM like a process killed by the signal.
    """
    try:
        yield
    except SIGTERMException:
        _exit_stopped(trainer, stage, hint, "terminated by SIGTERM", signal.SIGTERM)
    except SystemExit as stop:
        # Lightning answers Ctrl-C with "attempting graceful shutdown" and sys.exit(1): a failed run's status
        if stop.code == 1 and trainer.interrupted:
            _exit_stopped(trainer, stage, hint, "interrupted (Ctrl-C)", signal.SIGINT)
        raise


def _exit_stopped(trainer: L.Trainer, stage: str, hint: str | None, how: str, signum: int) -> NoReturn:
    if hint is None:
        ckpt = last_checkpoint(trainer)
        hint = (
            f"the last checkpoint is {ckpt.resolve()}: resume with ckpt_path={ckpt.resolve()}"
            if ckpt is not None
            else "no checkpoint was saved before the signal: rerun from scratch"
        )
    msg = f"{stage} {how} at epoch {trainer.current_epoch}, step {trainer.global_step}; {hint}"
    log.error(msg)
    print(msg, file=sys.stderr, flush=True)
    sys.exit(128 + signum)


def check_model_matches_data(model_target: str, data_target: str, source: str) -> None:
    """Refuse a classifier on reconstruction data and a reconstructor on classification data.

    Before, ``eval.py ckpt_path=<classifier> data=tiny`` exited 0 and ``train.py experiment=classify data=tiny`` ended
    in an unrelated ``rotate_touches`` TypeError.

    Args:
        model_target, data_target: the ``_target_`` of the model and data configs.
        source: what holds the model, for the message (``ckpt_path=...``, ``experiment=classify``).
    Raises:
        ValueError: naming the source, what it holds and the ``data=`` presets that fit it.
    """
    models = {"ClassificationModule": "cls", "ReconstructionModule": "recon"}
    datas = {"ClassificationDataModule": "cls", "ReconstructionDataModule": "recon"}
    model = next((v for k, v in models.items() if model_target.endswith(k)), None)
    data = next((v for k, v in datas.items() if data_target.endswith(k)), None)
    if model is None or data is None or model == data:
        return
    what = {"cls": "a classifier", "recon": "a reconstruction model"}[model]
    data_kind = {"cls": "classification data", "recon": "reconstruction data"}[data]
    fits = "cls_tiny, cls_small, cls_paper" if model == "cls" else "tiny, small, paper"
    raise ValueError(
        f"{source} holds {what} ({model_target}) but data= gives {data_kind} ({data_target}): give data= a preset "
        f"that fits it ({fits})"
    )


def fix_test_touches(data_cfg: DictConfig) -> None:
    """Give every reconstruction test sample ``max_touches`` touches (``data.test.num_touches``), in place.

    The reconstruction datasets draw T in [min_touches, max_touches] per sample; the test modes mask to the first
    k = 2, 5, 10 touches, which only means k touches when every test sample has at least k. Classification data
    and an explicit ``data.test.num_touches`` are left alone.
    """
    if not str(data_cfg.get("_target_", "")).endswith("ReconstructionDataModule") or not data_cfg.get("test"):
        return
    if data_cfg.test.get("num_touches") is None and data_cfg.get("max_touches") is not None:
        with open_dict(data_cfg):
            data_cfg.test.num_touches = int(data_cfg.max_touches)
        log.info("test split: every sample gets data.max_touches=%d touches", int(data_cfg.max_touches))
