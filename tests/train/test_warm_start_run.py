"""``train.py init_from=... freeze=[...]``: a run starts from another run's weights and keeps the frozen part fixed."""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from conftest import compose_config
from omegaconf import OmegaConf, open_dict


def _synthetic_cfg(overrides: list[str], out: Path):
    cfg = compose_config("train", ["experiment=smoke", *overrides], out)
    with open_dict(cfg):
        cfg.data = OmegaConf.create({"_target_": "synthetic.SyntheticReconDataModule", "batch_size": 2, "n": 2})
        cfg.model.metric_points = 100
        cfg.model.eval_touches = [2]
        cfg.model.export = False
        cfg.model.refine = False
    return cfg


def test_a_run_starts_from_another_runs_weights_and_keeps_the_frozen_part(tmp_path: Path) -> None:
    from train import train

    torch.manual_seed(123)
    source = hydra.utils.instantiate(_synthetic_cfg([], tmp_path / "old").model)
    ckpt = tmp_path / "old.ckpt"
    torch.save({"state_dict": source.state_dict()}, ckpt)
    old = source.state_dict()

    overrides = [f"init_from={ckpt}", "freeze=[net.visual]", "trainer.max_epochs=1", "test=false", "seed=7"]
    out = train(_synthetic_cfg(overrides, tmp_path / "new"))
    new = torch.load(Path(out["output_dir"]) / "checkpoints" / "last.ckpt", weights_only=True)["state_dict"]
    visual = [k for k in new if k.startswith("net.visual.")]
    assert visual and all(torch.equal(new[k], old[k]) for k in visual)  # weights and BatchNorm statistics
    moved = [k for k in new if k.startswith("net.deformer.") and not torch.equal(new[k], old[k])]
    assert moved  # the rest of the model trained
