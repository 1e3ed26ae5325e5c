"""``eval.py cls_fuse=[...]``: a trained classifier tested together with others, on the same touches."""

from __future__ import annotations

import json
from pathlib import Path

import hydra
import pytest
import torch
from conftest import compose_config
from omegaconf import OmegaConf, open_dict

from tvrecon.report.fused_classifiers import data_mismatch


def _cls_run(run: Path, seed: int, num_touches: int = 2, n: int = 6) -> Path:
    """A classification run folder (config + untrained weights) on the synthetic data; returns its checkpoint."""
    overrides = ["experiment=classify", f"model.num_touches={num_touches}", "model.net.num_classes=3", f"seed={seed}"]
    cfg = compose_config("train", overrides, run)
    with open_dict(cfg):
        cfg.data = OmegaConf.create(
            {"_target_": "synthetic.SyntheticClassificationDataModule", "num_touches": 2, "batch_size": 3, "n": n}
        )
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    torch.manual_seed(seed)
    model = hydra.utils.instantiate(cfg.model)
    (run / "checkpoints").mkdir()
    ckpt = run / "checkpoints" / "last.ckpt"
    torch.save({"state_dict": model.state_dict()}, ckpt)
    return ckpt


def _eval(tmp_path: Path, name: str, overrides: list[str]) -> dict:
    from eval import evaluate

    out = evaluate(compose_config("eval", overrides, tmp_path / name))
    [result] = out["results"]
    return result


def test_a_classifier_fused_with_itself_scores_as_alone_and_another_is_combined(tmp_path: Path) -> None:
    a, b = _cls_run(tmp_path / "a", seed=0), _cls_run(tmp_path / "b", seed=1)
    alone = _eval(tmp_path, "alone", [f"ckpt_path={a}"])
    itself = _eval(tmp_path, "itself", [f"ckpt_path={a}", f"cls_fuse=[{a}]"])
    assert itself["confusion"] == alone["confusion"] and itself["accuracy"] == alone["accuracy"]
    assert itself["name"] == "Late fusion (mean_log_prob, beyond the paper): Tactile classifier + Tactile classifier"
    assert itself["fused_with"] == [str(a)]
    assert "2" in itself["accuracy_other"]  # the fusion is always tested with another object's touches too
    other = _eval(tmp_path, "ab", [f"ckpt_path={a}", f"cls_fuse=[{tmp_path / 'b'}]", "cls_fuse_rule=mean_prob"])
    assert other["fused_with"] == [str(b)] and other["fusion_rule"] == "mean_prob"
    assert sum(map(sum, other["confusion"]["2"])) == sum(map(sum, alone["confusion"]["2"]))  # the same test draws
    saved = json.loads((tmp_path / "ab" / "00_a" / "metrics.json").read_text())
    assert saved["fused_with"] == [str(b)]


def test_fusion_refuses_other_data_no_common_touch_count_and_reconstructors(tmp_path: Path) -> None:
    from eval import evaluate

    a = _cls_run(tmp_path / "a", seed=0)
    other_data = _cls_run(tmp_path / "c", seed=2, n=9)
    with pytest.raises(ValueError, match=r"c/checkpoints/last.ckpt was trained on other data .*n: 6 vs 9"):
        evaluate(compose_config("eval", [f"ckpt_path={a}", f"cls_fuse=[{other_data}]"], tmp_path / "e1"))
    one = _cls_run(tmp_path / "one", seed=3, num_touches=1)  # the paper's model for N = 1 answers only one touch
    with pytest.raises(ValueError, match=r"no touch count is both tested .*\[2\].*\[1\]"):
        evaluate(compose_config("eval", [f"ckpt_path={a}", f"cls_fuse=[{one}]"], tmp_path / "e2"))
    recon = tmp_path / "r" / ".hydra"
    recon.mkdir(parents=True)
    OmegaConf.save(compose_config("train", ["experiment=smoke"], tmp_path / "r"), recon / "config.yaml")
    (tmp_path / "r" / "checkpoints").mkdir()
    torch.save({"state_dict": {}}, tmp_path / "r" / "checkpoints" / "last.ckpt")
    with pytest.raises(ValueError, match="not a classifier: only classifiers fuse"):
        evaluate(compose_config("eval", [f"ckpt_path={a}", f"cls_fuse=[{tmp_path / 'r'}]"], tmp_path / "e3"))


def test_data_mismatch_lets_members_add_inputs_and_ignore_images_they_do_not_read() -> None:
    base = OmegaConf.create({"tactile_size": 112, "library": {"protocol": "shared_base"}, "batch_size": 32})
    cloud = OmegaConf.create(
        {"tactile_size": 224, "library": {"protocol": "shared_base"}, "batch_size": 8, "patches": True}
    )
    assert data_mismatch(base, cloud, reads_images=False) == []
    assert data_mismatch(base, cloud, reads_images=True) == ["tactile_size"]
    cloud.library.protocol = "unseen"
    assert data_mismatch(base, cloud, reads_images=False) == ["library.protocol"]
