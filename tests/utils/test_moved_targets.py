"""Run folders of an earlier layout: their ``_target_`` strings are rewritten to the modules that hold the names now."""

from __future__ import annotations

import importlib

import hydra
import pytest
from omegaconf import OmegaConf

from tvrecon.utils.moved_targets import MOVED_MODULES, upgrade_target, upgrade_targets


@pytest.mark.parametrize("old", sorted(MOVED_MODULES))
def test_the_map_names_gone_modules_and_existing_ones(old: str) -> None:
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)
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
    assert upgrade_target("tvrecon.tables.main") == "tvrecon.report.tables.main"
