"""A NaN in a cached entry's tactile images is refused naming that entry's file (not the whole cache)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra.utils import instantiate

from tvrecon.data.cache.store import cache_key
from tvrecon.data.presets import compose_preset

TINY = ["train.num_objects=1", "touches_per_object=1", "sensor.resolution=[6,6]", "sensor.layers=3", "press.n_grid=32"]


def test_nan_in_cached_tactile_names_its_cache_entry(tmp_path: Path) -> None:
    dm = instantiate(compose_preset("cls_tiny", [*TINY, f"cache_dir={tmp_path}"]), _convert_="all")
    ds = dm.make_dataset("train")
    arrays, hit = ds.raw(0)
    assert not hit and np.isfinite(arrays["tactile"]).all()
    key = cache_key(ds.spec(0))
    poisoned = dict(arrays)
    poisoned["tactile"] = arrays["tactile"].copy()
    poisoned["tactile"].flat[0] = np.nan
    ds.cache.save(key, poisoned)  # a valid entry (its checksum matches) that holds a NaN, as a diverged press writes
    with pytest.raises(ValueError) as err:
        ds.raw(0)
    name, instance = ds.object_of(0)
    assert str(err.value).startswith(f"the tactile images of split 'train' item 0 ({name}, instance {instance}) hold")
    assert f"cache entry {ds.cache.path(key)}. Delete that file" in str(err.value)
    ds.cache.path(key).unlink()  # what the message says: the item is simulated again
    assert np.isfinite(ds.raw(0)[0]["tactile"]).all()
