"""Evaluate trained checkpoints on the test split and write the paper's Tables 2, 3 and 4.

    python eval.py ckpt_path=logs/train/runs/<time>/checkpoints/last.ckpt
    python eval.py run_dir=logs/train/multiruns/<time>        # every run below (one per experiment / seed)
    python eval.py run_dir=... data=paper trainer=gpu          # another data preset or accelerator
    python eval.py run_dir=<paper N=10 run> cls_fuse=[<contact cloud run>]   # two classifiers' answers combined

Each checkpoint is rebuilt from its run's ``.hydra/config.yaml`` (model and, unless ``data=`` is given, data), then
tested with 2, 5 and 10 touches (reconstruction: plus the no-touch "Visual" mode of a fusion model, and the
blank-view "Tactile" mode of the tactile-only model) or 1 to 10 touches (classifiers). Output in the eval run
folder (``logs/eval/runs/<time>``): ``<run>/metrics.json``, ``<run>/meshes/*.obj``, ``<run>/renders/test_<class>.png``,
``tables/table{2,3,4}.{md,csv}`` and ``tables/tables.md``, and the tables are printed.
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
from omegaconf import DictConfig, OmegaConf, open_dict  # noqa: E402

from tvrecon.report.fused_classifiers import (  # noqa: E402
    TrainedClassifier,
    fuse_data_config,
    fuse_into,
    load_trained_classifier,
)
from tvrecon.report.run_report import report_tables, save_results  # noqa: E402
from tvrecon.report.table_format import Table  # noqa: E402
from tvrecon.report.tables import data_protocol  # noqa: E402
from tvrecon.train.run_control import (  # noqa: E402
    check_model_matches_data,
    exit_on_sigterm,
    fix_test_touches,
)
from tvrecon.utils.checkpoint import CorruptCheckpointError, load_run  # noqa: E402
from tvrecon.utils.cli_errors import hydra_task, run_hydra_cli  # noqa: E402
from tvrecon.utils.run_options import check_run_options  # noqa: E402

log = logging.getLogger("eval")

TRAIN_HINT = (
    "train one first with `python train.py experiment=smoke` (or experiment=<name>); checkpoints are written to "
    "logs/train/runs/<time>/checkpoints/ and sweeps to logs/train/multiruns/<time>/<num>_<experiment>/checkpoints/"
)


def pick_checkpoint(ckpt_dir: Path, prefer: str = "best") -> Path | None:
    """The best (non-``last``, newest) or ``last`` checkpoint of a run's ``checkpoints`` folder, None if empty."""
    if prefer not in ("best", "last"):
        raise ValueError(f"prefer must be 'best' or 'last', got {prefer!r}")
    ckpts = sorted(ckpt_dir.glob("*.ckpt"), key=lambda p: p.stat().st_mtime)
    last = [p for p in ckpts if p.stem.startswith("last")]
    best = [p for p in ckpts if not p.stem.startswith("last")]
    order = (best[::-1] + last[::-1]) if prefer == "best" else (last[::-1] + best[::-1])
    return order[0] if order else None


def find_checkpoints(ckpt_path: str | None, run_dir: str | None, prefer: str = "best") -> list[Path]:
    """Resolve ``ckpt_path`` or every run below ``run_dir`` to checkpoint files.

    Raises:
        FileNotFoundError: the checkpoint / folder does not exist or holds no checkpoint (the message names the
            path and the command that makes one).
        ValueError: neither or both of ``ckpt_path`` and ``run_dir`` given.
    """
    if (ckpt_path is None) == (run_dir is None):
        raise ValueError(
            "give exactly one of ckpt_path=<file.ckpt> or run_dir=<run or multirun folder>, e.g. "
            "`python eval.py ckpt_path=logs/train/runs/<time>/checkpoints/last.ckpt`"
        )
    if ckpt_path is not None:
        path = Path(ckpt_path)
        if not path.is_file():
            raise FileNotFoundError(f"checkpoint {path} does not exist: {TRAIN_HINT}")
        return [path]
    root = Path(run_dir)  # type: ignore[arg-type]
    if not root.is_dir():
        raise FileNotFoundError(f"run_dir {root} does not exist: {TRAIN_HINT}")
    found = []
    for ckpt_dir in sorted(root.rglob("checkpoints")):
        if ckpt_dir.is_dir() and (ckpt := pick_checkpoint(ckpt_dir, prefer)) is not None:
            found.append(ckpt)
    if not found:
        raise FileNotFoundError(f"no checkpoints/*.ckpt below {root}: {TRAIN_HINT}")
    return found


def evaluate_checkpoint(ckpt: Path, cfg: DictConfig, out_dir: Path) -> dict[str, Any]:
    """Test one checkpoint; returns its result dict (also written to ``<out_dir>/metrics.json``)."""
    state, run_cfg = load_run(
        ckpt, "eval.py", "it rebuilds the model from it, so evaluate checkpoints inside their train.py run folder"
    )
    members = fused_members(cfg, str(run_cfg.model._target_), ckpt)
    trained_data = OmegaConf.create(OmegaConf.to_container(run_cfg.data, resolve=False))  # before data= replaces it
    with open_dict(run_cfg):
        run_cfg.paths = OmegaConf.create(OmegaConf.to_container(cfg.paths, resolve=True))
        run_cfg.paths.output_dir = str(out_dir)
        if cfg.get("data") is not None:
            run_cfg.data = cfg.data
        target = str(run_cfg.model._target_)
        if target.endswith("ClassificationModule"):
            run_cfg.model.eval_touches = list(cfg.cls_touches)
            if cfg.get("cls_headings") is not None:
                run_cfg.model.headings = int(cfg.cls_headings)
            if members:
                fuse_data_config(trained_data, run_cfg.data, members)
        else:
            run_cfg.model.eval_touches = list(cfg.eval_touches)
            run_cfg.model.export = bool(cfg.export)
            run_cfg.model.touch_controls = bool(cfg.get("touch_controls", False))
            run_cfg.model.refine = bool(cfg.get("refine", False))
    check_model_matches_data(str(run_cfg.model._target_), str(run_cfg.data.get("_target_", "")), f"ckpt_path={ckpt}")
    fix_test_touches(run_cfg.data)
    L.seed_everything(int(cfg.seed), workers=True)
    datamodule: L.LightningDataModule = hydra.utils.instantiate(run_cfg.data)
    model: L.LightningModule = hydra.utils.instantiate(run_cfg.model)
    if hasattr(model, "output_dir"):
        model.output_dir = str(out_dir)
    trainer: L.Trainer = hydra.utils.instantiate(
        cfg.trainer, logger=False, callbacks=[], default_root_dir=str(out_dir), enable_checkpointing=False
    )
    model.load_state_dict(state["state_dict"])
    recalibrated = recalibrate_statistics(model, datamodule, cfg)
    rule = str(cfg.get("cls_fuse_rule", "mean_log_prob"))
    if members:
        fuse_into(model, members, rule)
    if eval_split(cfg) == "val":
        # the validation split: for choosing evaluation settings without the test split (no paper tables)
        with exit_on_sigterm(trainer, f"evaluation of {ckpt}", "nothing was written for it: run eval.py again"):
            logged = trainer.validate(model=model, datamodule=datamodule)
        result = {"task": "validation", "name": run_cfg.get("experiment_name")}
        result["val"] = {str(k): float(v) for d in logged for k, v in d.items()}
        if run_cfg.model.get("headings") is not None:
            result["headings"] = int(run_cfg.model.headings)
    else:
        with exit_on_sigterm(trainer, f"evaluation of {ckpt}", "nothing was written for it: run eval.py again"):
            trainer.test(model=model, datamodule=datamodule)
        result = getattr(model, "test_results", None)
        if result is None:
            raise RuntimeError(f"{type(model).__name__} produced no test_results for {ckpt}")
        if int(cfg.get("fusion_share_batches") or 0) > 0:
            if getattr(getattr(model, "net", None), "fusion", None) is not None:
                result = {**result, "fusion_share": measure_fusion_share(model, datamodule, cfg)}
            else:
                log.info("fusion_share_batches: %s has no Agg blocks (not a fusion model); not measured", ckpt)
    result = {
        **result,
        "seed": run_cfg.get("seed"),
        "checkpoint": str(ckpt),
        "data_protocol": data_protocol(run_cfg.data),
    }
    if recalibrated:
        result = {**result, "bn_recalibrated": recalibrated}
    if members:
        result = {**result, "fused_with": [str(m.ckpt) for m in members], "fusion_rule": rule}
    if trainer.is_global_zero:
        save_results(result, out_dir)
    return result


def fused_members(cfg: DictConfig, target: str, ckpt: Path) -> list[TrainedClassifier]:
    """The classifiers ``cfg.cls_fuse`` names (run folders or checkpoints), rebuilt; [] when it names none.

    Raises:
        ValueError: ``cls_fuse`` with a reconstruction model, or a run folder holding several runs.
    """
    paths = [Path(str(p)) for p in (cfg.get("cls_fuse") or [])]
    if not paths:
        return []
    if not target.endswith("ClassificationModule"):
        raise ValueError(f"cls_fuse fuses classifiers, but {ckpt} holds {target}: drop cls_fuse for it")
    members = []
    for path in paths:
        if not path.exists():
            raise FileNotFoundError(f"cls_fuse=[{path}]: no such run folder or checkpoint; {TRAIN_HINT}")
        found = find_checkpoints(str(path), None) if path.is_file() else find_checkpoints(None, str(path), cfg.prefer)
        if len(found) != 1:
            raise ValueError(f"cls_fuse: {path} holds {len(found)} runs; name one run folder or checkpoint each")
        members.append(load_trained_classifier(found[0]))
    return members


def _last_instead(ckpt: Path) -> Path | None:
    """The run's ``last.ckpt`` when ``ckpt`` is another (best) checkpoint of the same folder, else None."""
    last = ckpt.parent / "last.ckpt"
    return last if last.is_file() and last.resolve() != ckpt.resolve() else None


def measure_fusion_share(model: L.LightningModule, datamodule: L.LightningDataModule, cfg: DictConfig) -> dict:
    """The touches' share of a fusion model's visual features (:mod:`tvrecon.report.fusion_share`) over the first
    ``cfg.fusion_share_batches`` test batches with the most touches evaluated; logged and returned."""
    from itertools import islice

    from tvrecon.report.fusion_share import fusion_share

    k = max(int(t) for t in cfg.eval_touches)
    share = fusion_share(model, islice(datamodule.test_dataloader(), int(cfg.fusion_share_batches)), k)
    stages = ", ".join(
        f"stage {j}: {100 * s['added_to_visual']:.2f}% of the visual features on {100 * s['pixels_reached']:.1f}% of "
        f"the pixels"
        for j, s in share["stages"].items()
    )
    log.info(
        "fusion share with %d touches over %d test samples: %s; final mesh moved %.4f (mesh scale %.3f)",
        k, share["samples"], stages, share["mesh_moved"], share["mesh_scale"],
    )  # fmt: skip
    return share


def recalibrate_statistics(model: L.LightningModule, datamodule: L.LightningDataModule, cfg: DictConfig) -> dict:
    """With ``cfg.bn_recalibrate_batches`` = K > 0: recompute the model's BatchNorm statistics over K training
    batches (:mod:`tvrecon.train.bn_recalibrate`) with the touches of ``cfg.bn_recalibrate_touches`` ("train": each
    sample's count drawn as in a training step; "max": all ``max_touches``, as validation). Returns what was done
    (``{}`` when K = 0), for metrics.json.

    Raises:
        ValueError: K < 0, an unknown touch choice, or a model that is not a reconstruction model.
    """
    k = int(cfg.get("bn_recalibrate_batches") or 0)
    if k < 0:
        raise ValueError(f"bn_recalibrate_batches must be >= 0 (0 = the checkpoint's own statistics), got {k}")
    if k == 0:
        return {}
    touches = str(cfg.get("bn_recalibrate_touches", "train"))
    if not hasattr(model, "training_mask"):
        raise ValueError(
            f"bn_recalibrate_batches is for reconstruction runs (the touches of a training step); "
            f"{type(model).__name__} is not one: set bn_recalibrate_batches=0"
        )
    masks = {"train": model.training_mask, "max": model.full_mask}
    if touches not in masks:
        raise ValueError(f"bn_recalibrate_touches must be 'train' or 'max', got {touches!r}")
    from tvrecon.train.bn_recalibrate import batchnorm_statistics, recalibrate_module, statistics_shift, worst_layers

    datamodule.setup("fit")
    torch.manual_seed(int(cfg.seed))  # the training touch counts drawn, and the loader's shuffle
    before = batchnorm_statistics(model)
    loader = datamodule.train_dataloader()
    used = min(k, len(loader))  # the split may hold fewer batches than asked for: metrics.json records those used
    if used < k:
        log.warning("bn_recalibrate_batches=%d: the training split holds %d batches; all %d are used", k, used, used)
    layers = recalibrate_module(model, loader, used, masks[touches])
    after = batchnorm_statistics(model)
    shift = statistics_shift(before, after)
    worst = worst_layers(before, after)
    for group, g in shift.items():
        log.info(
            "BatchNorm statistics of %s (%d layers) recomputed: the stored ones put the data's mean up to %.2f "
            "stored std off and its spread up to %.2fx off", group, g["layers"], g["mean_shift"], g["std_ratio"],
        )  # fmt: skip
    asked = {"batches_requested": k} if used < k else {}
    return {"batches": used, **asked, "touches": touches, "layers": layers, "shift": shift, "worst_layers": worst}


def eval_split(cfg: DictConfig) -> str:
    """``cfg.split``: "test" (default, the paper's tables) or "val" (the validation split, metrics only)."""
    split = str(cfg.get("split", "test"))
    if split not in ("test", "val"):
        raise ValueError(f"split must be 'test' or 'val', got {split!r}")
    return split


def validation_text(results: list[dict[str, Any]]) -> str:
    """Each run's validation metrics (``split=val``) as a Markdown table, one row a checkpoint."""
    keys = sorted({k for r in results for k in r.get("val", {})})
    rows = [[str(r["checkpoint"])] + [f"{r['val'][k]:.4f}" if k in r.get("val", {}) else "-" for k in keys]
            for r in results]  # fmt: skip
    return Table("Validation split", ["checkpoint", *keys], rows).to_markdown()


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Evaluate every checkpoint named by ``cfg`` and write/print the tables. Returns results and table text.

    In a sweep (``run_dir``) a truncated or corrupt best checkpoint falls back to the run's ``last.ckpt`` with a
    warning; a run whose checkpoints are all unreadable, or whose folder has no ``.hydra/config.yaml``, is skipped
    with a warning and the tables of the other runs are still written (the skipped files are returned under
    ``"skipped"``); a single ``ckpt_path`` that cannot be read raises
    :class:`~tvrecon.utils.checkpoint.CorruptCheckpointError` naming the file.
    """
    check_run_options(cfg)  # seed, torch_threads, trainer counts: errors name the key and the value
    if cfg.get("torch_threads"):
        torch.set_num_threads(int(cfg.torch_threads))
    ckpts = find_checkpoints(cfg.get("ckpt_path"), cfg.get("run_dir"), str(cfg.get("prefer", "best")))
    out_root = Path(cfg.paths.output_dir)
    results = []
    skipped: list[str] = []
    for i, ckpt in enumerate(ckpts):
        name = f"{i:02d}_{ckpt.resolve().parent.parent.name}"
        log.info("[%d/%d] evaluating %s", i + 1, len(ckpts), ckpt)
        try:
            results.append(evaluate_checkpoint(ckpt, cfg, out_root / name))
        except CorruptCheckpointError as err:
            if cfg.get("run_dir") is None:
                raise
            last = _last_instead(ckpt)
            if last is not None:
                log.warning("%s: %s; evaluating that run's %s instead", ckpt, err, last.name)
                try:
                    results.append(evaluate_checkpoint(last, cfg, out_root / name))
                    continue
                except CorruptCheckpointError as err_last:
                    err = err_last
            log.warning("skipping %s: %s (evaluate that run with prefer=last, or retrain it)", ckpt, err)
            skipped.append(str(ckpt))
        except FileNotFoundError as err:  # e.g. a run folder without .hydra/config.yaml: the sweep goes on
            if cfg.get("run_dir") is None:
                raise
            log.warning("skipping %s: %s", ckpt, err)
            skipped.append(str(ckpt))
    if not results:
        raise ValueError(
            f"no checkpoint below {cfg.get('run_dir')} could be evaluated (truncated or corrupt checkpoints, or run "
            f"folders without .hydra/config.yaml; the warnings above name each): {skipped}"
        )
    if eval_split(cfg) == "val":
        text = validation_text(results)
        print("\n" + text, flush=True)
    else:
        text = report_tables(results, out_root)
    if skipped:
        log.warning("tables leave out %d run(s) whose checkpoint is unreadable: %s", len(skipped), ", ".join(skipped))
    return {"results": results, "tables": text, "output_dir": str(out_root), "skipped": skipped}


PROG = "python eval.py"


@hydra.main(version_base="1.3", config_path="configs", config_name="eval.yaml")
@hydra_task(PROG)
def main(cfg: DictConfig) -> None:
    evaluate(cfg)


if __name__ == "__main__":
    run_hydra_cli(main, prog=PROG)  # errors: one line, exit 2 (bad input) / 1 / 130; --debug keeps the traceback
