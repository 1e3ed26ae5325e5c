"""A resumed train.py run keeps the CSV loss history logged before its checkpoint (Lightning's CSVLogger deletes it)."""

from __future__ import annotations

import csv
from pathlib import Path

import torch
from conftest import compose_config
from omegaconf import OmegaConf, open_dict

from tvrecon.train.csv_resume import rows_before_checkpoint


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_rows_before_checkpoint_drops_what_a_cut_off_run_logged_after_it(tmp_path: Path) -> None:
    metrics = tmp_path / "metrics.csv"
    metrics.write_text(
        "epoch,step,train/loss,val/chamfer\n"
        ",0,,\n"  # the learning-rate monitor's rows have no epoch
        "0,4,0.9,\n"
        "0,9,,20.0\n"  # epoch 0's validation at its last step
        "1,14,0.7,\n"
        "1,19,,18.0\n"
        "2,24,0.5,\n"  # epoch 2, after the checkpoint: logged again by the resumed run
        "bad,,1.0,\n"
    )
    ckpt = tmp_path / "last.ckpt"
    torch.save({"epoch": 1, "global_step": 20, "state_dict": {}}, ckpt)  # the end of epoch 1 (10 steps an epoch)
    kept = rows_before_checkpoint(metrics, ckpt)
    assert [(r.get("epoch"), r["step"]) for r in kept] == [
        (None, "0"),
        ("0", "4"),
        ("0", "9"),
        ("1", "14"),
        ("1", "19"),
    ]
    assert kept[2] == {"epoch": "0", "step": "9", "val/chamfer": "20.0"}  # empty cells dropped
    torch.save({"epoch": 1, "global_step": 15, "state_dict": {}}, ckpt)  # a checkpoint in the middle of epoch 1
    assert [r["step"] for r in rows_before_checkpoint(metrics, ckpt)] == ["0", "4", "9", "14"]
    assert rows_before_checkpoint(tmp_path / "missing.csv", ckpt) == []


def test_resumed_run_keeps_the_epochs_before_its_checkpoint(tmp_path: Path) -> None:
    from train import train

    def run(epochs: int, ckpt: Path | None = None) -> None:
        overrides = [f"trainer.max_epochs={epochs}", "logger=csv", "test=false"]
        if ckpt is not None:
            overrides.append(f"ckpt_path={ckpt}")
        cfg = compose_config("train", ["experiment=smoke", *overrides], tmp_path)
        with open_dict(cfg):
            cfg.data = OmegaConf.create({"_target_": "synthetic.SyntheticReconDataModule", "batch_size": 2, "n": 4})
            cfg.model.metric_points = 100
            cfg.model.export = False
        train(cfg)

    run(1)
    metrics = tmp_path / "csv" / "metrics.csv"
    first = _rows(metrics)
    assert {r["epoch"] for r in first} == {"", "0"}  # "": the learning-rate monitor's rows
    run(2, tmp_path / "checkpoints" / "last.ckpt")
    resumed = _rows(metrics)
    assert {r["epoch"] for r in resumed} == {"", "0", "1"}  # epoch 0 was deleted by the logger before the fix
    epoch0 = [r for r in resumed if r["epoch"] in ("", "0") and int(r["step"]) < 2]  # 2 steps an epoch
    assert len(epoch0) == len(first)  # kept once, not duplicated
    assert [r["val/chamfer"] for r in epoch0 if r.get("val/chamfer")] == [
        r["val/chamfer"] for r in first if r.get("val/chamfer")
    ]
    assert any(r.get("val/chamfer") for r in resumed if r["epoch"] == "1")
