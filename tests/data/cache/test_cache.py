"""Content-addressed sample cache: keys, hit/miss, invalidation, corruption recovery, atomic writes."""

import dataclasses
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from tvrecon.data.cache.store import CACHE_VERSION, SampleCache, cache_key, canonical_json


@dataclasses.dataclass
class _Cfg:
    E: float = 3.0
    resolution: tuple[int, int] = (16, 16)


def _spec(**over):
    spec = {"mesh": {"class": "torus", "instance": 3}, "sensor": _Cfg(), "touch_seed": 7, "render": {"fov": 35.0}}
    spec.update(over)
    return spec


def test_key_is_canonical_and_sensitive():
    a = {"b": 1, "a": [1.5, (2, 3)], "c": _Cfg()}
    b = {"c": {"E": 3.0, "resolution": [16, 16]}, "a": [1.5, [2, 3]], "b": 1}
    assert canonical_json(a) == canonical_json(b)
    assert cache_key(a) == cache_key(b)
    assert len(cache_key(a)) == 64
    assert cache_key(_spec()) != cache_key(_spec(sensor=_Cfg(E=3.0000001)))
    assert cache_key(_spec()) != cache_key(_spec(touch_seed=8))
    assert cache_key(_spec()) != cache_key(_spec(), version=CACHE_VERSION + "x")
    assert cache_key({"x": np.float32(0.5), "t": torch.tensor([1.0, 2.0])}) == cache_key(
        {"x": 0.5, "t": {"__ndarray__": "float32", "shape": [2], "data": [1.0, 2.0]}}
    )


def test_bad_spec_raises():
    with pytest.raises(ValueError, match="non-finite"):
        cache_key({"x": float("nan")})
    with pytest.raises(ValueError, match="cannot put an object"):
        cache_key({"x": object()})


def test_sharded_layout_and_hit_miss(tmp_path: Path):
    cache = SampleCache(tmp_path)
    calls = []

    def make():
        calls.append(1)
        return {"img": torch.arange(12, dtype=torch.float32).reshape(3, 4), "label": 5}

    a, hit_a = cache.get_or_create(_spec(), make)
    b, hit_b = cache.get_or_create(_spec(), make)
    assert (hit_a, hit_b) == (False, True)
    assert len(calls) == 1
    for name in a:
        assert a[name].dtype == b[name].dtype
        np.testing.assert_array_equal(a[name], b[name])
    key = cache_key(_spec())
    assert cache.path(key) == tmp_path / key[:2] / f"{key}.npz"
    assert cache.path(key).is_file() and key in cache
    assert cache.size_bytes() == cache.path(key).stat().st_size


def test_config_change_is_a_miss(tmp_path: Path):
    cache = SampleCache(tmp_path)
    cache.get_or_create(_spec(), lambda: {"v": np.zeros(3)})
    out, hit = cache.get_or_create(_spec(sensor=_Cfg(resolution=(8, 8))), lambda: {"v": np.ones(3)})
    assert not hit
    np.testing.assert_array_equal(out["v"], np.ones(3))
    assert len(list(tmp_path.glob("*/*.npz"))) == 2


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage"])
def test_corrupt_entry_is_warned_and_regenerated(tmp_path: Path, caplog, damage: str):
    cache = SampleCache(tmp_path, compress=False)
    data = {"v": np.arange(1000, dtype=np.float32)}
    cache.get_or_create(_spec(), lambda: data)
    path = cache.path(cache_key(_spec()))
    raw = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "flip":  # flip one byte inside the stored array data (zip CRC or our checksum must catch it)
        i = raw.find(np.arange(1000, dtype=np.float32)[500:502].tobytes())
        assert i > 0
        path.write_bytes(raw[:i] + bytes([raw[i] ^ 0xFF]) + raw[i + 1 :])
    else:
        path.write_bytes(b"not an npz at all")
    calls = []

    def make():
        calls.append(1)
        return data

    with caplog.at_level(logging.WARNING, logger="tvrecon.data.cache.store"):
        out, hit = cache.get_or_create(_spec(), make)
    assert not hit and calls == [1]
    assert any(str(path) in r.getMessage() and "corrupt" in r.getMessage() for r in caplog.records)
    np.testing.assert_array_equal(out["v"], data["v"])
    again, hit = cache.get_or_create(_spec(), make)
    assert hit and calls == [1]


def test_wrong_key_in_file_is_detected(tmp_path: Path, caplog):
    cache = SampleCache(tmp_path)
    k1, k2 = cache_key({"a": 1}), cache_key({"a": 2})
    cache.save(k1, {"v": np.zeros(2)})
    cache.path(k2).parent.mkdir(parents=True, exist_ok=True)
    cache.path(k2).write_bytes(cache.path(k1).read_bytes())
    with caplog.at_level(logging.WARNING):
        assert cache.load(k2) is None
    assert "corrupt cache entry" in caplog.text
    assert not cache.path(k2).exists()


def test_atomic_write_leaves_no_temp_files(tmp_path: Path):
    cache = SampleCache(tmp_path)
    for i in range(5):
        cache.save(cache_key({"i": i}), {"v": np.full(4, i)})
    files = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert len(files) == 5 and all(p.suffix == ".npz" and not p.name.startswith(".") for p in files)


def test_failed_write_leaves_nothing(tmp_path: Path):
    cache = SampleCache(tmp_path)
    key = cache_key({"i": 0})
    with pytest.raises(ValueError, match="dtype=object"):
        cache.save(key, {"v": np.array([object()], dtype=object)})
    with pytest.raises(ValueError, match="reserved"):
        cache.save(key, {"__key__": np.zeros(1)})
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


def test_interrupted_write_keeps_old_entry(tmp_path: Path, monkeypatch):
    cache = SampleCache(tmp_path)
    key = cache_key({"i": 0})
    cache.save(key, {"v": np.zeros(3)})

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(KeyboardInterrupt):
        cache.save(key, {"v": np.ones(3)})
    np.testing.assert_array_equal(cache.load(key)["v"], np.zeros(3))
    assert len([p for p in tmp_path.rglob("*") if p.is_file()]) == 1


def test_disabled_cache_always_generates(tmp_path: Path):
    cache = SampleCache(None)
    n = []
    for _ in range(2):
        _, hit = cache.get_or_create({"a": 1}, lambda: n.append(1) or {"v": np.zeros(1)})
        assert not hit
    assert len(n) == 2 and cache.size_bytes() == 0
    with pytest.raises(ValueError, match="disabled"):
        cache.path("ab" * 32)
    with pytest.raises(ValueError, match="hex digest"):
        SampleCache(tmp_path).path("../etc")


def test_unreadable_entry_is_reported_not_deleted_and_entries_get_umask_mode(tmp_path, monkeypatch) -> None:
    """A permission error was treated as corruption (file deleted); entries were written 0600."""
    from tvrecon.utils.atomic import default_file_mode

    cache = SampleCache(tmp_path)
    path = cache.save("a" * 64, {"x": np.zeros(3)})
    assert (path.stat().st_mode & 0o777) == default_file_mode()

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(np, "load", denied)  # chmod 0 does not stop root, so fake the other user's entry
    with pytest.raises(ValueError, match="cannot be read"):
        cache.load("a" * 64)
    assert path.exists()


def test_read_only_cache_is_reported_before_generating(tmp_path: Path, monkeypatch) -> None:
    """A read-only cache with one missing entry generated it, then crashed storing it."""
    import tempfile

    cache = SampleCache(tmp_path / "cache")
    cache.get_or_create(_spec(touch_seed=1), lambda: {"x": np.zeros(3)})
    calls = []

    def read_only(*args, **kwargs):  # what a read-only file system answers (root ignores chmod, so no chmod here)
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    arrays, hit = cache.get_or_create(_spec(touch_seed=1), lambda: calls.append(1) or {"x": np.ones(3)})
    assert hit and arrays["x"].sum() == 0  # reading a read-only cache still works
    with pytest.raises(ValueError, match=r"cache .*cache is read-only \(Read-only file system\).*missing"):
        cache.get_or_create(_spec(touch_seed=2), lambda: calls.append(1) or {"x": np.ones(3)})
    assert calls == []  # nothing was generated
