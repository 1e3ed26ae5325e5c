"""Train.py / eval.py fail in one line with an exit code, and the silent cases fail loudly.

Items 1 (one line, exit 2/1/130, --debug), 3 (limit_train_batches=0, a classifier on reconstruction data, a NaN
loss stops training) and 4 (unknown config groups list what exists).
"""

from __future__ import annotations

import runpy
import signal
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
from conftest import ROOT, compose_config
from omegaconf import OmegaConf, open_dict

from tvrecon.models.finite_loss import NonFiniteLossError, check_finite_loss


class InterruptAtStep(L.Callback):
    """Test-only: Ctrl-C (a KeyboardInterrupt) after training batch ``step``."""

    def __init__(self, step: int = 1) -> None:
        self.step = step

    def on_train_batch_end(self, trainer: L.Trainer, *args: object) -> None:
        if trainer.global_step == self.step:
            raise KeyboardInterrupt


class NanWeightsAtStep(L.Callback):
    """Test-only: every weight becomes NaN before training batch ``step`` (a run that diverged)."""

    def __init__(self, step: int = 1) -> None:
        self.step = step

    def on_train_batch_start(self, trainer: L.Trainer, module: L.LightningModule, *args: object) -> None:
        if trainer.global_step == self.step:
            with torch.no_grad():
                for p in module.parameters():
                    p.fill_(float("nan"))


def _cls_cfg(run: Path, callbacks: dict, epochs: int = 3):
    overrides = ["experiment=classify", "model.num_touches=2", "model.net.num_classes=3"]
    overrides += [f"trainer.max_epochs={epochs}", "+trainer.num_sanity_val_steps=0", "test=false", "~logger"]
    cfg = compose_config("train", overrides, run)
    with open_dict(cfg):
        cfg.data = OmegaConf.create(
            {"_target_": "synthetic.SyntheticClassificationDataModule", "num_touches": 2, "batch_size": 3, "n": 3}
        )
        cfg.callbacks = OmegaConf.create(callbacks)
        cfg.callbacks.model_checkpoint = {
            "_target_": "lightning.pytorch.callbacks.ModelCheckpoint",
            "dirpath": str(run / "checkpoints"),
            "save_last": True,
            "save_top_k": 1,
            "save_weights_only": True,
        }
    return cfg


def _run_script(script: str, argv: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    """``python <script> argv...`` in this process (its ``__main__`` block); returns the exit status."""
    path = ROOT / script
    monkeypatch.setattr(sys, "argv", [str(path), *argv])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(path), run_name="__main__")
    return int(exc.value.code)


def _run_train_cli(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    return _run_script("train.py", argv, monkeypatch)


def _one_error_line(err: str, prog: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"{prog}: error: "), lines[0]
    return lines[0]


@pytest.mark.parametrize(
    ("override", "listed"),
    [("experiment=bogus", "Available options in 'experiment': chart_based, "), ("data=bogus", "cls_tiny, ")],
)
def test_unknown_config_group_is_one_line_listing_the_options(
    override: str, listed: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run_train_cli([override, f"hydra.run.dir={tmp_path}"], monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err, "python train.py")
    assert f"Could not find '{override.split('=')[0]}/bogus'" in line and listed in line
    assert "Config search path" not in line and "Traceback" not in line


def test_bad_input_in_the_run_is_one_line_and_exit_2_and_debug_keeps_the_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["experiment=smoke", "trainer.max_epochs=0", f"hydra.run.dir={tmp_path}", "~logger"]
    assert _run_train_cli(args, monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err, "python train.py")
    assert "trainer.max_epochs=0 trains nothing" in line and "eval.py ckpt_path=" in line
    with pytest.raises(ValueError, match="max_epochs=0 trains nothing"):
        _run_train_cli([*args, "--debug"], monkeypatch)


def test_limit_train_batches_0_is_refused(tmp_path: Path) -> None:
    """`train.py +trainer.limit_train_batches=0` trained nothing and exited 0 with the untrained tables."""
    from train import check_training_length, train

    cfg = compose_config("train", ["experiment=smoke", "+trainer.limit_train_batches=0"], tmp_path)
    with pytest.raises(ValueError, match=r"limit_train_batches=0 trains on no batch.*limit_train_batches=N"):
        train(cfg)
    assert not (tmp_path / "metrics.json").exists()
    check_training_length(compose_config("train", ["experiment=smoke", "+trainer.limit_train_batches=1"], tmp_path))
    check_training_length(compose_config("train", ["experiment=smoke", "+trainer.limit_train_batches=0.5"], tmp_path))


def test_nan_loss_stops_training_naming_the_step_the_terms_and_the_fix(tmp_path: Path) -> None:
    from train import train

    cfg = _cls_cfg(tmp_path / "run", {"nan": {"_target_": "test_cli_faults.NanWeightsAtStep", "step": 1}})
    with pytest.raises(NonFiniteLossError) as exc:
        train(cfg)
    msg = str(exc.value)
    assert "training loss is nan at epoch 1, step 1 (terms: loss=nan, acc=" in msg
    assert "Lower the learning rate (now " in msg and "model.optimizer.lr" in msg


def test_check_finite_loss_passes_finite_and_names_every_term() -> None:
    module = L.LightningModule()
    check_finite_loss(module, {"loss": torch.tensor(1.0), "edge": torch.tensor(0.5)})
    with pytest.raises(NonFiniteLossError, match=r"loss is inf at epoch 0, step 0 \(terms: loss=inf, edge=0.5\)"):
        check_finite_loss(module, {"loss": torch.tensor(float("inf")), "edge": torch.tensor(0.5)})


def test_ctrl_c_in_training_exits_130_naming_the_checkpoint_to_resume_from(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Lightning answers Ctrl-C with a graceful shutdown and exit 1 (a failed run); now 130 and the resume hint."""
    from train import train

    run = tmp_path / "run"
    cfg = _cls_cfg(run, {"ctrl_c": {"_target_": "test_cli_faults.InterruptAtStep", "step": 2}})
    handler = signal.getsignal(signal.SIGINT)
    try:
        with pytest.raises(SystemExit) as exc:
            train(cfg)
    finally:
        signal.signal(signal.SIGINT, handler)  # Lightning ignores further Ctrl-C during its shutdown
    assert exc.value.code == 130
    last = (run / "checkpoints" / "last.ckpt").resolve()
    err = capsys.readouterr().err
    assert "training interrupted (Ctrl-C) at epoch 1, step 2;" in err and f"resume with ckpt_path={last}" in err


def test_a_classifier_on_reconstruction_data_is_refused() -> None:
    """`eval.py ckpt_path=<classifier> data=tiny` exited 0; `train.py experiment=classify data=tiny` ended
    in an unrelated rotate_touches TypeError."""
    from eval import check_model_matches_data

    cls = "tvrecon.models.lit_cls.ClassificationModule"
    recon = "tvrecon.models.lit_recon.ReconstructionModule"
    with pytest.raises(ValueError, match=r"c.ckpt holds a classifier .* reconstruction data .*cls_tiny, cls_small"):
        check_model_matches_data(cls, "tvrecon.data.datamodule.ReconstructionDataModule", "ckpt_path=c.ckpt")
    with pytest.raises(ValueError, match=r"holds a reconstruction model .* classification data .*tiny, small"):
        check_model_matches_data(recon, "tvrecon.data.datamodule.ClassificationDataModule", "ckpt_path=r.ckpt")
    check_model_matches_data(cls, "tvrecon.data.datamodule.ClassificationDataModule", "ckpt_path=c.ckpt")
    check_model_matches_data(cls, "synthetic.SyntheticClassificationDataModule", "c.ckpt")  # test data: no check


def test_train_cli_classifier_on_reconstruction_data_is_one_line_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["experiment=classify", "data=tiny", f"hydra.run.dir={tmp_path}", "~logger"]
    assert _run_train_cli(args, monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err, "python train.py")
    assert "experiment=classify holds a classifier" in line and "reconstruction data" in line and "cls_tiny" in line


def test_eval_cli_classifier_on_reconstruction_data_is_one_line_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "cls_run"
    cfg = _cls_cfg(run, {}, epochs=1)
    (run / ".hydra").mkdir(parents=True)
    with open_dict(cfg):
        cfg.data = compose_config("train", ["data=cls_tiny"], run).data  # the run's own (classification) data
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    model = __import__("hydra").utils.instantiate(cfg.model)
    (run / "checkpoints").mkdir()
    torch.save({"state_dict": model.state_dict()}, run / "checkpoints" / "last.ckpt")
    argv = [f"ckpt_path={run / 'checkpoints' / 'last.ckpt'}", "data=tiny", f"hydra.run.dir={tmp_path / 'e'}"]
    assert _run_script("eval.py", argv, monkeypatch) == 2
    line = _one_error_line(capsys.readouterr().err, "python eval.py")
    assert "holds a classifier" in line and "reconstruction data" in line and "data=" in line


def test_a_refused_run_leaves_no_run_folder_and_a_refused_resume_keeps_its_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    fresh = tmp_path / "fresh"
    args = ["experiment=smoke", "model.optimizer.lr=-1", "~logger"]
    assert _run_train_cli([*args, f"hydra.run.dir={fresh}"], monkeypatch) == 2
    assert "model.optimizer.lr must be > 0" in _one_error_line(capsys.readouterr().err, "python train.py")
    assert not fresh.exists() and tmp_path.is_dir()  # Hydra's folder for the refused run is gone, nothing above it
    # the same mistake in the command that resumes a run: its folder and everything in it stay
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"weights")
    (run / "train.log").write_text("epoch 3 done\n")
    assert _run_train_cli([*args, f"hydra.run.dir={run}"], monkeypatch) == 2
    assert (run / "checkpoints" / "last.ckpt").read_bytes() == b"weights"
    assert (run / "train.log").read_text().startswith("epoch 3 done")
    assert (run / ".hydra" / "config.yaml").is_file()
