"""Fixtures of the training tests: compose the real configs/train.yaml with the hydra compose API."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, open_dict

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
os.environ.setdefault("PROJECT_ROOT", str(ROOT))
if str(ROOT) not in sys.path:  # train.py / eval.py live at the project root
    sys.path.insert(0, str(ROOT))


def compose_config(name: str, overrides: Sequence[str], out_dir: Path) -> DictConfig:
    """Compose ``configs/<name>.yaml`` with overrides; paths point into ``out_dir`` (no hydra runtime needed)."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        cfg = compose(config_name=name, overrides=list(overrides))
    with open_dict(cfg):
        cfg.paths.output_dir = str(out_dir)
        cfg.paths.log_dir = str(out_dir / "logs")
        cfg.paths.work_dir = str(out_dir)
    return cfg


@pytest.fixture
def compose_train(tmp_path: Path) -> Callable[..., DictConfig]:
    def _compose(overrides: Sequence[str] = (), out_dir: Path | None = None) -> DictConfig:
        return compose_config("train", overrides, out_dir or tmp_path / "run")

    return _compose


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: on the shared 2-core CI machine two threads contend and run ~10x slower."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
