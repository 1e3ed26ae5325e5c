"""``compile="auto"`` in the data pipeline: ``pregenerate`` and the datamodule settle it per process from
the touches that process will simulate (the policy itself: ``tests/sim/mpm/test_compile_policy.py``). Nothing is
simulated or compiled: the presses are stubbed."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hydra.utils import instantiate
from tiny_press import TINY_PRESS

from tvrecon.data.dataset_base import GeneratedDataset
from tvrecon.data.generation.pool import pregenerate
from tvrecon.data.presets import compose_preset
from tvrecon.sim.mpm.compiled import policy

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def datamodule(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """A cls_tiny datamodule of 4 objects x 3 touches on an empty cache; no compile cache variable; a C++ compiler."""
    monkeypatch.delenv(policy.CACHE_ENV, raising=False)
    monkeypatch.setattr(policy, "cpp_compiler", lambda: "/usr/bin/c++")
    os.environ.setdefault("PROJECT_ROOT", str(ROOT))
    overrides = ["train.num_objects=4", "touches_per_object=3", *TINY_PRESS, f"cache_dir={tmp_path}"]
    return instantiate(compose_preset("cls_tiny", overrides), _convert_="all")


def test_pregenerate_settles_auto_for_its_process(monkeypatch, datamodule, tmp_path: Path) -> None:
    """4 uncached items of 3 touches in one process: 12 touches of this pad (each ``touch_work`` reference touches);
    compiled at a threshold of just that, not just above, and the compile cache then goes under the data cache."""
    probe = datamodule.make_dataset("train")
    (h, w), layers = probe.sensor.resolution, probe.sensor.layers
    counted = 12 * policy.touch_work(h * w * layers, probe.press.n_grid)
    for threshold, expected in ((counted * 1.001, False), (counted, True)):
        monkeypatch.setattr(policy, "AUTO_MIN_TOUCHES_COLD", threshold)
        ds = datamodule.make_dataset("train")
        assert ds.press.compile == "auto"
        monkeypatch.setattr(ds, "raw", lambda i: (None, False))  # no simulation: the plan alone is tested
        pregenerate(ds, workers=1, progress=False)
        assert ds.press.compile is expected and ds.simulator.compile is expected
        assert (os.environ.get(policy.CACHE_ENV) == str(tmp_path.resolve() / policy.CACHE_SUBDIR)) is expected


def test_the_datamodule_plans_the_touches_its_loaders_simulate(monkeypatch, datamodule) -> None:
    seen: list[tuple[str, int]] = []
    monkeypatch.setattr(GeneratedDataset, "plan_compile", lambda self, touches: seen.append((self.split, touches)))
    datamodule.num_workers = 2
    datamodule.setup("fit")
    assert ("train", 4 * 3 // 2) in seen  # nothing cached: each of the 2 loader workers simulates half
