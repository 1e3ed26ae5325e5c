"""``data/touch=<policy>`` replaces a reconstruction preset's touches whole: the presets' shuffled sweep is a touch
config of its own (``touch/paper_sweep_shuffled.yaml``), so no key of it is left over for another policy."""

from __future__ import annotations

from pathlib import Path

import hydra
import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _touch(overrides: list[str]):
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        return compose(config_name="train", overrides=overrides).data.touch


@pytest.mark.parametrize("preset", ["tiny", "small", "paper_cpu", "paper"])
def test_cone_touches_replace_the_sweep_of_every_reconstruction_preset(preset: str) -> None:
    sweep = _touch([f"data={preset}"])
    assert sweep._target_.endswith("PaperSweepTouchPolicy") and sweep.order == "shuffled"
    cone = _touch([f"data={preset}", "data/touch=cone"])
    assert "order" not in cone
    policy = hydra.utils.instantiate(cone, _convert_="all")
    assert type(policy).__name__ == "ConeTouchPolicy"
