"""train.py / eval.py refuse every way of training nothing, and options read as numbers name their key and value.

Also: a frozen module needs weights to keep, a NaN result prints as ``nan`` (not the ``-`` of a mode not evaluated),
and ``bn_recalibrate_batches`` records the batches it used.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import hydra
import lightning as L
import pytest
import torch
from conftest import ROOT, compose_config
from omegaconf import OmegaConf, open_dict

from tvrecon.report.table_format import fmt
from tvrecon.train.warm_start import FreezeParameters
from tvrecon.utils.run_options import check_run_options


def _smoke(overrides: list[str], out: Path):
    return compose_config("train", ["experiment=smoke", *overrides], out)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("trainer.max_epochs=abc", "trainer.max_epochs must be a whole number, got 'abc'"),
        ("trainer.max_epochs=2.5", "trainer.max_epochs must be a whole number, got 2.5"),
        ("seed=abc", "seed must be a whole number, got 'abc'"),
        ("torch_threads=-1", "torch_threads (null = torch's default) must be >= 1, got -1"),
        ("model.optimizer.lr=-1", "model.optimizer.lr must be > 0, got -1"),
        ("model.optimizer.lr=abc", "model.optimizer.lr must be a number, got 'abc'"),
    ],
)
def test_run_options_name_key_and_value(tmp_path: Path, override: str, message: str) -> None:
    with pytest.raises((TypeError, ValueError)) as err:
        check_run_options(_smoke([override], tmp_path))
    assert str(err.value).startswith(message)


def test_run_options_accept_the_presets(tmp_path: Path) -> None:
    check_run_options(_smoke([], tmp_path))
    check_run_options(_smoke(["seed=null", "torch_threads=null", "trainer.max_epochs=-1"], tmp_path))
    check_run_options(compose_config("eval", ["ckpt_path=x.ckpt"], tmp_path))


def test_every_way_of_training_nothing_is_refused(tmp_path: Path) -> None:
    from train import check_training_length

    with pytest.raises(ValueError, match=r"trainer.max_steps=0 trains nothing"):
        check_training_length(_smoke(["+trainer.max_steps=0"], tmp_path))
    with pytest.raises(ValueError, match=r"trainer.max_time=00:00:00:00 trains nothing"):
        check_training_length(_smoke(["+trainer.max_time=00:00:00:00"], tmp_path))
    check_training_length(_smoke(["+trainer.max_steps=0", f"ckpt_path={tmp_path / 'x.ckpt'}"], tmp_path))
    check_training_length(_smoke(["+trainer.max_steps=5"], tmp_path))
    check_training_length(_smoke(["+trainer.max_time=00:00:01:00"], tmp_path))


def test_freeze_needs_weights_to_keep(tmp_path: Path) -> None:
    from train import check_freeze

    with pytest.raises(ValueError, match=r"freeze=\['net.visual'\] without init_from keeps randomly initialised"):
        check_freeze(_smoke(["freeze=[net.visual]"], tmp_path))
    check_freeze(_smoke(["freeze=[net.visual]", f"init_from={tmp_path / 'x.ckpt'}"], tmp_path))
    check_freeze(_smoke(["freeze=[net.visual]", f"ckpt_path={tmp_path / 'x.ckpt'}"], tmp_path))
    check_freeze(_smoke([], tmp_path))


class _Tiny(L.LightningModule):
    def __init__(self) -> None:
        super().__init__()
        self.net = torch.nn.Sequential(torch.nn.Linear(2, 2), torch.nn.Linear(2, 1))


def test_freezing_the_whole_model_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match=r"freeze=\['net'\] fixes all 9 parameters of the model: nothing would train"):
        FreezeParameters(["net"]).freeze_before_training(_Tiny())
    part = _Tiny()
    FreezeParameters(["net.0"]).freeze_before_training(part)  # a part: the rest trains
    assert [p.requires_grad for p in part.parameters()] == [False, False, True, True]


def test_nan_prints_as_nan_and_a_missing_value_as_dash() -> None:
    assert fmt(float("nan")) == "nan"
    assert fmt(None) == "-"
    assert fmt(1.234) == "1.23"


def test_bn_recalibration_records_the_batches_used(tmp_path: Path) -> None:
    from eval import recalibrate_statistics

    cfg = _smoke([], tmp_path)
    with open_dict(cfg):
        cfg.data = OmegaConf.create({"_target_": "synthetic.SyntheticReconDataModule", "batch_size": 2, "n": 2})
    model = hydra.utils.instantiate(cfg.model)
    datamodule = hydra.utils.instantiate(cfg.data)
    done = recalibrate_statistics(
        model, datamodule, compose_config("eval", ["ckpt_path=x.ckpt", "bn_recalibrate_batches=5"], tmp_path)
    )
    assert done["batches"] == 1 and done["batches_requested"] == 5  # the split holds one batch of 2 samples


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("+trainer.max_steps=0", "python train.py: error: trainer.max_steps=0 trains nothing"),
        ("seed=abc", "python train.py: error: seed must be a whole number, got 'abc' (str)"),
    ],
)
def test_train_cli_refuses_in_one_line(tmp_path: Path, override: str, message: str) -> None:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "experiment=smoke", override, f"hydra.run.dir={tmp_path}"],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("python train.py")]
    assert len(lines) == 1 and lines[0].startswith(message), proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "metrics.json").exists()


def test_cls_fuse_names_a_missing_folder(tmp_path: Path) -> None:
    from eval import fused_members

    missing = tmp_path / "no_such_run"
    cfg = compose_config("eval", ["ckpt_path=x.ckpt", f"cls_fuse=[{missing}]"], tmp_path)
    with pytest.raises(FileNotFoundError, match=rf"^cls_fuse=\[{missing}\]: no such run folder or checkpoint"):
        fused_members(cfg, "tvrecon.models.lit_cls.ClassificationModule", tmp_path / "x.ckpt")
