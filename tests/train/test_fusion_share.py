"""The touches' share of the fusion model's visual features (tvrecon.report.fusion_share): zero for Agg blocks that add
nothing (the control), positive once they do, and a clear error for a model without fusion."""

from __future__ import annotations

import pytest
import torch
from synthetic import SyntheticRecon
from torch.utils.data import DataLoader

from tvrecon.models.components.backbone import ResNet18Backbone
from tvrecon.models.components.fusion import TactileVisualFusion
from tvrecon.models.components.gcn import MeshDeformer
from tvrecon.models.components.reconstructor import TactileVisualReconstructor
from tvrecon.models.lit_recon import ReconstructionModule
from tvrecon.report.fusion_share import fusion_share


def _module(mode: str = "fusion") -> ReconstructionModule:
    torch.manual_seed(0)
    chans = list(ResNet18Backbone.channels)
    fusion = None if mode == "visual_only" else TactileVisualFusion(chans, chans)  # zero-initialised Agg blocks
    tactile = None if mode == "visual_only" else ResNet18Backbone()
    net = TactileVisualReconstructor(
        ResNet18Backbone(), tactile, fusion, MeshDeformer(chans, hidden=16, num_blocks=1), mode=mode
    )
    return ReconstructionModule(net, lambda p: torch.optim.AdamW(p, lr=1e-3))


def _batches() -> DataLoader:
    return DataLoader(SyntheticRecon(4, seed=0, touches=4), batch_size=2)


def test_agg_blocks_that_add_nothing_have_no_share():
    share = fusion_share(_module(), _batches(), touches=4)
    assert share["samples"] == 4 and share["touches"] == 4
    assert set(share["stages"]) == {"0", "1", "2", "3"}
    for s in share["stages"].values():
        assert s["added_to_visual"] == 0.0 and s["pixels_reached"] == 0.0
    assert share["mesh_moved"] < 1e-6 and share["mesh_scale"] > 0.01  # round-off of the fused maps' order


def test_agg_blocks_that_add_something_are_measured():
    module = _module()
    with torch.no_grad():
        for p in module.net.fusion.aggs.parameters():
            p.normal_(0.0, 0.1)
    share = fusion_share(module, _batches(), touches=4)
    for s in share["stages"].values():
        assert s["added_to_visual"] > 0 and 0 < s["pixels_reached"] <= 1
    # a 3x3 region per touch: part of the first stage's 16 x 16 map (64-pixel views), all of the last one's 2 x 2
    assert share["stages"]["0"]["pixels_reached"] < 0.5 and share["stages"]["3"]["pixels_reached"] == 1.0
    assert share["mesh_moved"] > 0
    assert module.training  # the module's mode is restored


def test_a_model_without_fusion_is_a_clear_error():
    with pytest.raises(ValueError, match="has none"):
        fusion_share(_module("visual_only"), _batches(), touches=2)
    with pytest.raises(ValueError, match="touches must be >= 1"):
        fusion_share(_module(), _batches(), touches=0)
    with pytest.raises(ValueError, match="at least one batch"):
        fusion_share(_module(), [], touches=2)
