"""The data presets resolve to pinned values, and their samples keep their pinned cache keys.

``fixtures/data_presets.json`` holds, for every preset of ``configs/data/``, the resolved ``data`` node as train.py
composes it (``data=<preset>`` in ``configs/train.yaml``) and as ``python -m tvrecon.data.generate`` composes it
(:func:`tvrecon.data.presets.compose_preset`), plus the ``data`` node of every experiment. It was written before the
presets were split into config groups, so the composed presets are proven to give the same values.
The one intended difference is ``touch._target_``, added when touch policies became pluggable: it
names the default policy, whose cache key it does not enter. Presets added later (``cls_paper_cpu``) were
written into the fixture the same way, without ``touch._target_``, and their other presets' entries left untouched
(``paper_cpu``: Table 1's reconstruction sizes on ``small``'s geometry, likewise without ``press.compile``
and ``device_tactile_size``).
The fixture was rewritten on purpose when the presets moved to the paper's touches (``touch/paper_sweep``,
the ``eip*`` pads and grids, the library's ``protocol``, cache version ``tvrecon-data-5``). ``press.collider_refine: 2``
was then added to ``press/eip_cpu`` (the object's table at the authors' spacing, so that thin parts are felt on the 64
grid): the presets on that block (``small``, ``cls_paper_cpu``, ``cls_sweep_cpu`` and their experiments) gained the key
in both fixtures, and their cache keys changed with it. ``tvrecon-data-6`` (the distance table over distinct surface
samples) changed every key and no value. ``touch.start: outside`` (each paper touch's position where its centre line
leaves the object, so a cube pressed at 45 degrees is no longer rejected and re-drawn off the sweep) was added to every
preset on ``touch/paper_sweep``; it enters the policy's cache key, so those presets' keys changed and the cone
presets' did not. ``patch_min_push`` / ``patch_min_push_fraction`` (the contact patches' load-time contact test, issue
24) were added to every entry of the first fixture; no cache key changed. The touch policies moved into
``tvrecon.data.touches``: every ``touch._target_`` of the first fixture follows them, and no cache key changed
(``TouchPolicy.key_target``).

``fixtures/data_cache_keys.json`` pins the cache key of the first item of each split of each preset: a change there
means every cached sample of that preset is regenerated, which must be a deliberate ``CACHE_VERSION`` bump (update
the fixture in the same commit).

Regenerate (only on purpose): ``python tests/data/test_preset_snapshot.py``.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.utils import instantiate
from omegaconf import OmegaConf

from tvrecon.data.cache.store import cache_key
from tvrecon.data.presets import compose_preset, default_cache_dir, preset_names

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
FIXTURES = Path(__file__).parent / "fixtures"
PRESETS_FIXTURE = FIXTURES / "data_presets.json"
KEYS_FIXTURE = FIXTURES / "data_cache_keys.json"
PRESETS = [
    "cls_paper",
    "cls_paper_cpu",
    "cls_small",
    "cls_sweep_cpu",
    "cls_tiny",
    "paper",
    "paper_cpu",
    "small",
    "tiny",
]
EXPERIMENTS = sorted(p.stem for p in (CONFIGS / "experiment").glob("*.yaml"))


def _portable(value: Any, root: str, cache: str) -> Any:
    """``value`` with the machine-dependent cache folder replaced by a placeholder."""
    if isinstance(value, dict):
        return {k: _portable(v, root, cache) for k, v in value.items()}
    if isinstance(value, list):
        return [_portable(v, root, cache) for v in value]
    if isinstance(value, str):
        return value.replace(cache, "<CACHE>").replace(root, "<ROOT>")
    return value


def _train_data(overrides: list[str]) -> dict[str, Any]:
    """Resolved ``data`` node of ``configs/train.yaml`` composed with ``overrides`` (as train.py does)."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        cfg = compose(config_name="train", overrides=overrides)
    root = os.environ.get("PROJECT_ROOT", ".")
    return _portable(OmegaConf.to_container(cfg.data, resolve=True), root, f"{root}/data/cache")


def _preset_data(name: str) -> dict[str, Any]:
    """Resolved preset as ``python -m tvrecon.data.generate preset=<name>`` composes it."""
    GlobalHydra.instance().clear()
    cfg = compose_preset(name)
    return _portable(OmegaConf.to_container(cfg, resolve=True), str(ROOT), str(default_cache_dir()))


def snapshot() -> dict[str, Any]:
    """Everything ``fixtures/data_presets.json`` pins."""
    return {
        "train": {name: _train_data([f"data={name}"]) for name in PRESETS},
        "generate": {name: _preset_data(name) for name in PRESETS},
        "experiment": {name: _train_data([f"experiment={name}"]) for name in EXPERIMENTS},
    }


def cache_keys(convert: str = "all") -> dict[str, dict[str, str]]:
    """Cache key of item 0 of every split of every preset (nothing is generated).

    ``convert``: Hydra's ``_convert_``; the generate CLI instantiates with ``"all"``, train.py with the default
    ``"none"`` (the touch policy then gets OmegaConf lists and dicts).
    """
    out = {}
    for name in PRESETS:
        GlobalHydra.instance().clear()
        dm = instantiate(compose_preset(name, ["cache_dir=null"]), _convert_=convert)
        out[name] = {split: cache_key(dm.make_dataset(split).spec(0)) for split in dm.available_splits()}
    return out


@pytest.fixture(scope="module")
def project_root() -> None:
    # PROJECT_ROOT decides the cache folder; tests/train/conftest.py sets it the same way
    os.environ.setdefault("PROJECT_ROOT", str(ROOT))


def test_preset_list_is_pinned():
    assert preset_names() == PRESETS


#: Keys added to every preset on purpose since the fixture was written (rewritten for the paper's touches),
#: with their value: ``press.compile`` (base/common.yaml: the fused kernels as a config field, outside
#: the cache key, so the pinned keys hold; ``auto`` makes the fast path the default) and
#: ``device_tactile_size`` (base/common.yaml: the tactile resize after the transfer to a GPU, a datamodule setting
#: that no dataset and no cache key sees). A key is its path in the ``data`` node.
ADDED: dict[tuple[str, ...], Any] = {("press", "compile"): "auto", ("device_tactile_size",): None}


def test_presets_resolve_to_pinned_values(project_root):
    expected = json.loads(PRESETS_FIXTURE.read_text())
    actual = snapshot()
    assert sorted(actual["experiment"]) == sorted(expected["experiment"])
    for how in ("train", "generate", "experiment"):
        for name, cfg in expected[how].items():
            got = actual[how][name]
            for path, value in ADDED.items():
                node = got
                for key in path[:-1]:
                    node = node[key]
                assert node.pop(path[-1]) == value, f"{how} {name}: {'.'.join(path)}"
            assert got == cfg, f"{how} {name}: the composed data config changed"


@pytest.mark.parametrize("convert", ["all", "none"])
def test_cache_keys_are_pinned(project_root, convert: str):
    assert cache_keys(convert) == json.loads(KEYS_FIXTURE.read_text())


def test_default_policy_key_ignores_how_it_is_written(project_root):
    """``touch.cone_deg=15`` (an int), the default policy with or without ``_target_``, or no touch block at all:
    one policy, one key."""
    expected = json.loads(KEYS_FIXTURE.read_text())["cls_small"]["train"]  # the presets still on the default policy
    for overrides in (["touch.cone_deg=15"], ["~touch._target_"], ["~touch"]):
        GlobalHydra.instance().clear()
        dm = instantiate(compose_preset("cls_small", ["cache_dir=null", *overrides]))
        assert cache_key(dm.make_dataset("train").spec(0)) == expected, overrides


if __name__ == "__main__":  # regenerate the fixtures (only when a change of values or keys is intended)
    os.environ.setdefault("PROJECT_ROOT", str(ROOT))
    FIXTURES.mkdir(exist_ok=True)
    PRESETS_FIXTURE.write_text(json.dumps(snapshot(), indent=1, sort_keys=True) + "\n")
    KEYS_FIXTURE.write_text(json.dumps(cache_keys(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {PRESETS_FIXTURE} and {KEYS_FIXTURE}", file=sys.stderr)
