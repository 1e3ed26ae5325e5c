"""Run folders of an earlier layout: their ``_target_`` strings are rewritten to the modules that hold the names now."""

from __future__ import annotations

import importlib
from pathlib import Path

import hydra
import pytest
import torch
from omegaconf import OmegaConf

from tvrecon.data.touches.policies import make_touch_policy
from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.utils.checkpoint import load_run
from tvrecon.utils.moved_targets import MOVED_MODULES, upgrade_target, upgrade_targets


@pytest.mark.parametrize("old", sorted(MOVED_MODULES))
def test_the_map_names_gone_modules_and_existing_ones(old: str) -> None:
    """Each old module is gone, or is a package now whose modules hold its names (``tvrecon.data.touches``)."""
    try:
        module = importlib.import_module(old)
    except ModuleNotFoundError:
        pass
    else:
        assert hasattr(module, "__path__"), f"{old} is still a module: its entry rewrites a path that works"
    importlib.import_module(MOVED_MODULES[old])


def test_an_old_run_config_is_rewritten_and_instantiates() -> None:
    cfg = OmegaConf.create(
        {
            "model": {
                "_target_": "tvrecon.models.lit_recon.ReconstructionModule",  # never moved: left alone
                "net": {"fusion": {"_target_": "tvrecon.models.fusion.TactileVisualFusion"}},
                "blocks": [{"_target_": "tvrecon.models.backbone.ResNet18Backbone"}],
            },
            "paths": {"output_dir": "${hydra:runtime.output_dir}"},  # resolvable only inside a Hydra run
        }
    )
    changed = upgrade_targets(cfg)
    assert changed == [
        ("tvrecon.models.fusion.TactileVisualFusion", "tvrecon.models.components.fusion.TactileVisualFusion"),
        ("tvrecon.models.backbone.ResNet18Backbone", "tvrecon.models.components.backbone.ResNet18Backbone"),
    ]
    assert cfg.model._target_ == "tvrecon.models.lit_recon.ReconstructionModule"
    assert OmegaConf.to_container(cfg.paths, resolve=False) == {"output_dir": "${hydra:runtime.output_dir}"}
    for target in (cfg.model.net.fusion._target_, cfg.model.blocks[0]._target_):
        assert hydra.utils.get_class(target).__module__.startswith("tvrecon.models.components.")
    assert upgrade_targets(cfg) == []  # a config of this release is left as it is


def test_upgrade_target_leaves_unknown_and_current_paths() -> None:
    assert upgrade_target("tvrecon.sim.press.EIPSimulator") == "tvrecon.sim.press.EIPSimulator"
    assert upgrade_target("torch.optim.AdamW") == "torch.optim.AdamW"
    assert upgrade_target("tvrecon.models.grad_norm.GradNormMonitor") == "tvrecon.train.grad_norm.GradNormMonitor"
    current = "tvrecon.data.touches.policies.ConeTouchPolicy"  # inside the package that replaced a moved module
    assert upgrade_target(current) == current


def test_a_checkpoint_of_the_previous_layout_loads(tmp_path: Path) -> None:
    """A run folder whose config names the modules of the previous layout (the network, the callbacks, the touch
    policy) loads: its checkpoint's weights go into the network its rewritten config builds, its callbacks build,
    and its touch policy keeps the cache key its samples were cached under."""
    run = tmp_path / "run"
    cfg = OmegaConf.create(
        {
            "model": {"net": {"_target_": "tvrecon.models.classifier.TactileClassifier", "num_classes": 3}},
            "callbacks": {
                "grad_norm": {"_target_": "tvrecon.models.grad_norm.GradNormMonitor"},
                "precise_bn": {"_target_": "tvrecon.models.bn_recalibrate.PreciseBatchNorm", "num_batches": 2},
            },
            "data": {"touch": {"_target_": "tvrecon.data.touch_sweep.PaperSweepTouchPolicy"}},
        }
    )
    (run / ".hydra").mkdir(parents=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    trained = TactileClassifier(num_classes=3, num_touches=1)
    ckpt = run / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir()
    torch.save({"state_dict": trained.state_dict(), "hyper_parameters": {"num_touches": 1}}, ckpt)

    state, run_cfg = load_run(ckpt, "test", "write the run's config")
    net = hydra.utils.instantiate(run_cfg.model.net, num_touches=1)
    net.load_state_dict(state["state_dict"])
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), trained.state_dict().values()))
    callbacks = [hydra.utils.instantiate(c) for c in run_cfg.callbacks.values()]
    assert [type(c).__module__ for c in callbacks] == ["tvrecon.train.grad_norm", "tvrecon.train.bn_recalibrate"]
    policy = make_touch_policy(run_cfg.data.touch)
    assert type(policy).__module__ == "tvrecon.data.touches.sweep"
    assert policy.cache_spec()["_target_"] == "tvrecon.data.touch_sweep.PaperSweepTouchPolicy"  # the samples' keys
