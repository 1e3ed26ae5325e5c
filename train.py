"""Train (then test) a tactile-visual reconstruction model or a tactile classifier with Lightning + Hydra.

    python train.py experiment=smoke                                  # tiny data on CPU, ends by printing the tables
    python train.py experiment=<name> data=<tiny|small|paper> trainer=<cpu|gpu|ddp>
    python train.py -m 'experiment=glob(*,exclude=[smoke,classify*])' data=paper trainer=gpu   # every recon model
    python train.py experiment=full ckpt_path=logs/train/runs/<time>/checkpoints/last.ckpt   # resume
    python train.py hparams_search=lr_wd                              # grid search with the basic sweeper
    python train.py experiment=touch_cascade init_from=<visual run>/checkpoints/last.ckpt 'freeze=[net.visual]'

Every run writes to its hydra folder (``logs/train/runs/<time>`` or ``.../multiruns/<time>/<num>_<experiment>``):
``checkpoints/`` (best by ``val/chamfer`` and last), ``csv/metrics.csv``, ``tensorboard/``, ``renders/`` (predicted
vs ground-truth mesh per epoch and per test class), ``meshes/*.obj``, ``metrics.json`` (test results),
``tables/`` (Markdown + CSV) and ``loss_curves.png``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent
os.environ.setdefault("PROJECT_ROOT", str(ROOT))

import hydra  # noqa: E402
import lightning as L  # noqa: E402
import torch  # noqa: E402
from lightning.pytorch.loggers import CSVLogger, Logger  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

from tvrecon.report.run_report import report_tables, save_results  # noqa: E402
from tvrecon.report.tables import data_protocol  # noqa: E402
from tvrecon.report.viz import plot_loss_curves  # noqa: E402
from tvrecon.train.csv_resume import restore_csv_history  # noqa: E402
from tvrecon.train.run_control import (  # noqa: E402
    check_model_matches_data,
    exit_on_sigterm,
    fix_test_touches,
)
from tvrecon.train.warm_start import FreezeParameters, load_initial_weights  # noqa: E402
from tvrecon.utils.checkpoint import check_checkpoint  # noqa: E402
from tvrecon.utils.cli_errors import hydra_task, run_hydra_cli  # noqa: E402
from tvrecon.utils.run_options import check_run_options  # noqa: E402

__all__ = ["check_freeze", "check_training_length", "instantiate_callbacks", "instantiate_loggers", "main", "train"]

log = logging.getLogger("train")


def instantiate_callbacks(cfg: DictConfig | None) -> list[L.Callback]:
    """Build every ``_target_`` entry of the ``callbacks`` config group (None -> no callbacks)."""
    if not cfg:
        return []
    if not isinstance(cfg, DictConfig):
        raise ValueError(f"callbacks config must be a mapping of name -> {{_target_: ...}}, got {type(cfg).__name__}")
    return [hydra.utils.instantiate(c) for c in cfg.values() if isinstance(c, DictConfig) and "_target_" in c]


def instantiate_loggers(cfg: DictConfig | None) -> list[Logger]:
    """Build every ``_target_`` entry of the ``logger`` config group (None -> no logger)."""
    if not cfg:
        return []
    if not isinstance(cfg, DictConfig):
        raise ValueError(f"logger config must be a mapping of name -> {{_target_: ...}}, got {type(cfg).__name__}")
    return [hydra.utils.instantiate(c) for c in cfg.values() if isinstance(c, DictConfig) and "_target_" in c]


def _csv_metrics(trainer: L.Trainer) -> Path | None:
    for lg in trainer.loggers:
        if isinstance(lg, CSVLogger):
            path = Path(lg.log_dir) / "metrics.csv"
            return path if path.is_file() else None
    return None


def check_training_length(cfg: DictConfig) -> None:
    """Refuse epoch (or batch) counts that would report an untrained model or never reach the test.

    ``trainer.max_epochs=0`` fits nothing, and the test would print Tables 3/4 of the random initial weights under
    the experiment's name; it is refused unless ``ckpt_path`` gives the weights (then only a warning: the checkpoint
    is tested as it is). ``max_epochs=-1`` is Lightning's "train forever": refused unless ``trainer.max_steps`` or
    ``trainer.max_time`` bounds the run, since without them no test or table ever comes.
    ``+trainer.limit_train_batches=0``, ``+trainer.max_steps=0`` and ``+trainer.max_time=00:00:00:00`` train on no
    batch: refused like ``max_epochs=0``.

    Raises:
        ValueError: naming the setting and what to pass instead.
    """
    trainer = cfg.get("trainer") or {}
    if not cfg.get("train") or trainer.get("fast_dev_run"):
        return
    limit = trainer.get("limit_train_batches")
    if limit is not None and not isinstance(limit, bool) and float(limit) == 0 and cfg.get("ckpt_path") is None:
        raise ValueError(
            f"trainer.limit_train_batches={limit} trains on no batch: the test and the tables would report the "
            f"untrained model as this experiment's result. Give a number of batches (+trainer.limit_train_batches=N, "
            f"N >= 1) or a fraction in (0, 1], or drop it to train on every batch"
        )
    max_steps = trainer.get("max_steps")
    if max_steps is not None and int(max_steps) == 0 and cfg.get("ckpt_path") is None:
        raise ValueError(
            "trainer.max_steps=0 trains nothing: the test and the tables would report the untrained model as this "
            "experiment's result. Give a number of steps (+trainer.max_steps=N, N >= 1; -1 = no limit), or test a "
            "trained checkpoint with `python eval.py ckpt_path=<run>/checkpoints/last.ckpt`"
        )
    max_time = trainer.get("max_time")
    if isinstance(max_time, str) and all(p.strip().isdigit() and int(p) == 0 for p in max_time.split(":")):
        raise ValueError(f"trainer.max_time={max_time} trains nothing: give a duration DD:HH:MM:SS above 0")
    if trainer.get("max_epochs") is None:
        return
    max_epochs = int(trainer.max_epochs)
    max_steps = trainer.get("max_steps")
    bounded = trainer.get("max_time") is not None or (max_steps is not None and int(max_steps) > 0)
    if max_epochs == 0:
        if cfg.get("ckpt_path") is None:
            raise ValueError(
                "trainer.max_epochs=0 trains nothing: the test and the tables would report the untrained model as "
                "this experiment's result. Train with trainer.max_epochs=N (N >= 1), or test a trained checkpoint "
                "with `python eval.py ckpt_path=<run>/checkpoints/last.ckpt`"
            )
        log.warning(
            "trainer.max_epochs=0: no training, the weights of ckpt_path=%s are tested as they are", cfg.ckpt_path
        )
    elif max_epochs == -1 and not bounded:
        raise ValueError(
            "trainer.max_epochs=-1 trains forever (Lightning's infinite mode), so the test and the tables never come: "
            "give a number of epochs (trainer.max_epochs=N), or bound the run with +trainer.max_time=DD:HH:MM:SS or "
            "+trainer.max_steps=N"
        )
    elif max_epochs < -1:
        raise ValueError(f"trainer.max_epochs={max_epochs} is not a number of epochs: use N >= 1 (or -1 with a bound)")


def check_freeze(cfg: DictConfig) -> None:
    """Refuse ``freeze=[...]`` without weights to keep: with neither ``init_from`` nor ``ckpt_path`` the frozen
    modules would stay at their random initialisation for the whole run, and its tables would report a model whose
    (say) image encoder never learnt anything.

    Raises:
        ValueError: naming the frozen modules and what to pass.
    """
    freeze = list(cfg.get("freeze") or [])
    if freeze and cfg.get("init_from") is None and cfg.get("ckpt_path") is None:
        raise ValueError(
            f"freeze={freeze} without init_from keeps randomly initialised modules fixed for the whole run: give the "
            f"weights to keep with init_from=<run>/checkpoints/last.ckpt, or drop freeze"
        )


def train(cfg: DictConfig) -> dict[str, Any]:
    """Fit then test the model described by ``cfg`` (the composed ``configs/train.yaml``).

    Returns:
        ``{"metrics": {name: float}, "result": test result dict | None, "tables": str, "output_dir": str,
        "best_ckpt": str | None}``.
    """
    check_run_options(cfg)  # seed, torch_threads, trainer counts, lr: errors name the key and the value
    check_training_length(cfg)
    check_freeze(cfg)
    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path is not None and not Path(ckpt_path).is_file():
        raise FileNotFoundError(
            f"ckpt_path={ckpt_path} does not exist: pass the checkpoints/last.ckpt of an earlier run to resume, "
            f"or drop ckpt_path to start from scratch"
        )
    if ckpt_path is not None:
        check_checkpoint(ckpt_path)  # a truncated file is named here, not in torch's "central directory" error
    if cfg.get("torch_threads"):
        torch.set_num_threads(int(cfg.torch_threads))
    if cfg.get("seed") is not None:
        L.seed_everything(int(cfg.seed), workers=True)
    out_dir = Path(cfg.paths.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    experiment = f"experiment={cfg.get('experiment_name')}"
    check_model_matches_data(str(cfg.model._target_), str(cfg.data.get("_target_", "")), experiment)
    fix_test_touches(cfg.data)
    log.info("Instantiating datamodule <%s>", cfg.data._target_)
    datamodule: L.LightningDataModule = hydra.utils.instantiate(cfg.data)
    log.info("Instantiating model <%s>", cfg.model._target_)
    model: L.LightningModule = hydra.utils.instantiate(cfg.model)
    if cfg.get("init_from") is not None:
        if ckpt_path is not None:
            log.warning(
                "ckpt_path=%s resumes the run: its weights replace those of init_from=%s", ckpt_path, cfg.init_from
            )
        load_initial_weights(model, cfg.init_from)
    callbacks = instantiate_callbacks(cfg.get("callbacks"))
    if cfg.get("freeze"):
        callbacks.append(FreezeParameters(list(cfg.freeze)))
    loggers = instantiate_loggers(cfg.get("logger"))
    if ckpt_path is not None:
        restore_csv_history(loggers, ckpt_path)  # the loss history before the checkpoint stays in csv/metrics.csv
    trainer: L.Trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    for lg in trainer.loggers:
        lg.log_hyperparams(OmegaConf.to_container(cfg, resolve=False))  # type: ignore[arg-type]

    if cfg.get("train"):
        log.info("Starting training")
        with exit_on_sigterm(trainer, "training"):
            trainer.fit(model=model, datamodule=datamodule, ckpt_path=ckpt_path)
    metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1}

    best = None
    if trainer.checkpoint_callback is not None and getattr(trainer.checkpoint_callback, "best_model_path", ""):
        best = trainer.checkpoint_callback.best_model_path
    result = None
    tables = ""
    if cfg.get("test"):
        log.info("Testing %s", best or "the current weights (no best checkpoint)")
        hint = f"the checkpoints are kept: test {best} again with `python eval.py ckpt_path={best}`" if best else None
        with exit_on_sigterm(trainer, "testing", hint):
            trainer.test(model=model, datamodule=datamodule, ckpt_path=best if best else None)
        metrics.update({k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1})
        result = getattr(model, "test_results", None)
        if result is not None and trainer.is_global_zero:
            result = {**result, "seed": cfg.get("seed"), "checkpoint": best, "data_protocol": data_protocol(cfg.data)}
            save_results(result, out_dir)
            if cfg.get("tables", True):
                tables = report_tables([result], out_dir)
            if cfg.get("explain_touches") and result.get("task") == "reconstruction":  # make demo (experiment=smoke)
                from tvrecon.report.demo_explain import explain_touches

                print("\n" + explain_touches(result), flush=True)  # what the run's own numbers say of the touches
    if trainer.is_global_zero:
        csv_path = _csv_metrics(trainer)
        if csv_path is not None:
            try:
                plot_loss_curves(csv_path, out_dir / "loss_curves.png")
            except ValueError as err:  # e.g. fast_dev_run logs nothing plottable
                log.warning("no loss curves: %s", err)
    return {"metrics": metrics, "result": result, "tables": tables, "output_dir": str(out_dir), "best_ckpt": best}


PROG = "python train.py"


@hydra.main(version_base="1.3", config_path="configs", config_name="train.yaml")
@hydra_task(PROG)
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the optimized metric for sweepers."""
    out = train(cfg)
    value = out["metrics"].get(str(cfg.get("optimized_metric")))
    return None if value is None else float(value)


if __name__ == "__main__":
    run_hydra_cli(main, prog=PROG)  # errors: one line, exit 2 (bad input) / 1 / 130; --debug keeps the traceback
