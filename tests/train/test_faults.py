"""Faults around training and evaluation: corrupt checkpoints, signals, degenerate epoch counts."""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
import pytest
import torch
from conftest import compose_config
from omegaconf import OmegaConf, open_dict

from tvrecon.utils.checkpoint import CorruptCheckpointError, check_checkpoint, load_run


def _synthetic_cfg(overrides: list[str], out: Path):
    cfg = compose_config("train", ["experiment=smoke", *overrides], out)
    with open_dict(cfg):
        cfg.data = OmegaConf.create({"_target_": "synthetic.SyntheticReconDataModule", "batch_size": 2, "n": 2})
        cfg.model.metric_points = 100
        cfg.model.eval_touches = [2]
        cfg.model.export = False
        cfg.model.refine = False
    return cfg


def _fake_run(run: Path, truncate: bool = False) -> Path:
    """A train.py run folder (``.hydra/config.yaml`` + ``checkpoints/last.ckpt``) of an untrained smoke model."""
    cfg = _synthetic_cfg([], run)
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    model = hydra.utils.instantiate(cfg.model)
    ckpt = run / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir()
    torch.save({"state_dict": model.state_dict()}, ckpt)
    if truncate:
        data = ckpt.read_bytes()
        ckpt.write_bytes(data[: len(data) // 2])
    return ckpt


def test_check_checkpoint_names_truncated_and_damaged_files(tmp_path: Path) -> None:
    path = tmp_path / "c.ckpt"
    torch.save({"state_dict": {"w": torch.randn(4000)}}, path)
    assert check_checkpoint(path) == path
    data = path.read_bytes()
    (tmp_path / "t.ckpt").write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptCheckpointError, match=r"checkpoint .*t\.ckpt is truncated or corrupt"):
        check_checkpoint(tmp_path / "t.ckpt")
    damaged = bytearray(data)
    damaged[len(data) // 2 : len(data) // 2 + 64] = b"x" * 64  # inside the tensor data: torch.load would accept it
    (tmp_path / "d.ckpt").write_bytes(bytes(damaged))
    with pytest.raises(CorruptCheckpointError, match=r"d\.ckpt .*CRC"):
        check_checkpoint(tmp_path / "d.ckpt")


def test_load_run_checks_the_config_the_file_and_upgrades_moved_targets(tmp_path: Path, caplog) -> None:
    ckpt = tmp_path / "lone" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    torch.save({"state_dict": {}}, ckpt)
    missing = r"who: .*lone/\.hydra/config\.yaml \(the config .*\) does not exist: do this"
    with pytest.raises(FileNotFoundError, match=missing):
        load_run(ckpt, "who", "do this")
    ckpt = _fake_run(tmp_path / "run")
    cfg = OmegaConf.load(ckpt.parent.parent / ".hydra" / "config.yaml")
    old = "tvrecon.models.fusion.TactileVisualFusion"  # the module's path before it moved
    cfg.model.net.fusion = {"_target_": old}
    OmegaConf.save(cfg, ckpt.parent.parent / ".hydra" / "config.yaml")
    with caplog.at_level(logging.INFO, logger="tvrecon.utils.checkpoint"):
        state, run_cfg = load_run(ckpt, "who", "do this")
    saved = torch.load(ckpt, weights_only=True)["state_dict"]
    assert state["state_dict"].keys() == saved.keys() and len(saved) > 0
    assert run_cfg.model.net.fusion._target_ == "tvrecon.models.components.fusion.TactileVisualFusion"
    assert "1 _target_ of an earlier release rewritten" in caplog.text
    data = ckpt.read_bytes()
    ckpt.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptCheckpointError, match=r"last\.ckpt is truncated or corrupt"):
        load_run(ckpt, "who", "do this")


def test_eval_sweep_skips_a_corrupt_checkpoint_and_prints_the_other_tables(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    from eval import evaluate

    sweep = tmp_path / "sweep"
    good = _fake_run(sweep / "0_smoke")
    bad = _fake_run(sweep / "1_smoke", truncate=True)
    ev = compose_config(
        "eval", [f"run_dir={sweep}", "eval_touches=[2]", "export=false", "+trainer.limit_test_batches=1"], tmp_path
    )
    with caplog.at_level(logging.WARNING, logger="eval"):
        out = evaluate(ev)
    assert [r["checkpoint"] for r in out["results"]] == [str(good)]
    assert out["skipped"] == [str(bad)]
    assert str(bad) in caplog.text and "truncated or corrupt" in caplog.text
    assert "Table 3" in capsys.readouterr().out and (tmp_path / "tables" / "table3.md").is_file()

    single = compose_config("eval", [f"ckpt_path={bad}"], tmp_path / "single")
    with pytest.raises(CorruptCheckpointError, match=rf"checkpoint {bad} is truncated or corrupt"):
        evaluate(single)


def test_resume_from_truncated_checkpoint_names_the_file(tmp_path: Path) -> None:
    from train import train

    bad = _fake_run(tmp_path / "old", truncate=True)
    cfg = _synthetic_cfg([f"ckpt_path={bad}"], tmp_path / "new")
    with pytest.raises(CorruptCheckpointError, match=rf"checkpoint {bad} is truncated"):
        train(cfg)


def test_sigterm_during_training_exits_nonzero_and_names_the_last_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Lightning turns SIGTERM into SystemExit(None) (exit 0, no message); train.py exits 143 naming last.ckpt."""
    from train import train

    run = tmp_path / "run"
    overrides = ["experiment=classify", "model.num_touches=2", "model.net.num_classes=3", "trainer.max_epochs=3"]
    overrides += ["+trainer.num_sanity_val_steps=0", "test=false", "~logger"]
    cfg = compose_config("train", overrides, run)
    with open_dict(cfg):  # one batch per epoch: SIGTERM in epoch 0, seen after epoch 0 wrote last.ckpt
        cfg.data = OmegaConf.create(
            {"_target_": "synthetic.SyntheticClassificationDataModule", "num_touches": 2, "batch_size": 3, "n": 3}
        )
        cfg.callbacks = OmegaConf.create({"sigterm": {"_target_": "synthetic.SigtermAtStep", "step": 1}})
        cfg.callbacks.model_checkpoint = {
            "_target_": "lightning.pytorch.callbacks.ModelCheckpoint",
            "dirpath": str(run / "checkpoints"),
            "save_last": True,
            "save_top_k": 1,
            "save_weights_only": True,
        }
    with pytest.raises(SystemExit) as exc:
        train(cfg)
    assert exc.value.code == 143
    last = (run / "checkpoints" / "last.ckpt").resolve()
    err = capsys.readouterr().err
    assert "training terminated by SIGTERM at epoch 1," in err and f"resume with ckpt_path={last}" in err


@pytest.mark.parametrize("epochs", [0, -1, -3])
def test_untrained_or_endless_epoch_counts_are_refused(epochs: int, tmp_path: Path) -> None:
    """max_epochs=0 printed the untrained model's tables as the experiment's; -1 trained forever without a word."""
    from train import train

    cfg = _synthetic_cfg([f"trainer.max_epochs={epochs}"], tmp_path)
    match = {0: r"max_epochs=0 trains nothing.*eval\.py ckpt_path=", -1: "trains forever.*max_time", -3: "N >= 1"}
    with pytest.raises(ValueError, match=match[epochs]):
        train(cfg)
    assert not (tmp_path / "metrics.json").exists()


def test_bounded_or_resumed_epoch_counts_pass_the_check(tmp_path: Path) -> None:
    from train import check_training_length

    check_training_length(_synthetic_cfg(["trainer.max_epochs=-1", "+trainer.max_time=00:00:01:00"], tmp_path))
    check_training_length(_synthetic_cfg(["trainer.max_epochs=-1", "+trainer.max_steps=10"], tmp_path))
    check_training_length(_synthetic_cfg(["trainer.max_epochs=0", f"ckpt_path={tmp_path / 'x.ckpt'}"], tmp_path))
    check_training_length(_synthetic_cfg(["trainer.max_epochs=0", "train=false"], tmp_path))
