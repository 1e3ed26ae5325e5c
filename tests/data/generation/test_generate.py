"""The generate CLI: writes the cache, resumes (second run skips everything), shards partition the items."""

from pathlib import Path

import pytest
from tiny_press import TINY_PRESS

from tvrecon.data.generate import main
from tvrecon.data.generation.args import parse_shard, parse_splits
from tvrecon.data.generation.pool import pregenerate, shard_indices
from tvrecon.data.presets import compose_preset

ARGS = [
    "preset=cls_tiny",
    "train.num_objects=3",
    "val.num_objects=1",
    "test.num_objects=1",
    "touches_per_object=2",
    *TINY_PRESS,
]


def test_cli_writes_cache_then_skips_everything(tmp_path: Path, capsys):
    args = ARGS + [f"cache_dir={tmp_path}", "workers=1"]
    first = main(args)
    assert [s.generated for s in first] == [3, 1, 1]
    assert [s.touches for s in first] == [6, 2, 2]
    assert len(list(tmp_path.glob("*/*.npz"))) == 5
    out = capsys.readouterr().out
    assert "touches/s" in out and "per 1000 samples" in out
    second = main(args)
    assert [s.generated for s in second] == [0, 0, 0]
    assert [s.skipped for s in second] == [3, 1, 1]
    # what the CLI wrote is exactly what the datamodule reads
    from hydra.utils import instantiate

    dm = instantiate(compose_preset("cls_tiny", [a for a in args if not a.startswith(("preset", "workers"))]))
    ds = dm.make_dataset("train")
    assert all(ds.raw(i)[1] for i in range(len(ds)))
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.suffix != ".npz"]


def test_cli_shard_and_split_selection(tmp_path: Path):
    args = ARGS + [f"cache_dir={tmp_path}", "workers=1", "splits=train", "--shard", "1/2"]
    (st,) = main(args)
    assert st.items == 1 and st.generated == 1  # items 0..2, shard 1 of 2 -> item 1
    dm_cfg = compose_preset("cls_tiny", [a for a in ARGS if not a.startswith("preset")] + [f"cache_dir={tmp_path}"])
    from hydra.utils import instantiate

    ds = instantiate(dm_cfg).make_dataset("train")
    assert [ds.is_cached(i) for i in range(3)] == [False, True, False]


def test_shards_partition_items_across_ranks():
    seen = []
    for i in range(3):
        for rank in range(2):
            seen += shard_indices(17, (i, 3), rank_world=(rank, 2))
    assert sorted(seen) == list(range(17))


def test_rank_from_environment(monkeypatch):
    monkeypatch.setenv("LOCAL_RANK", "1")
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.delenv("RANK", raising=False)
    assert shard_indices(6) == [1, 3, 5]


def test_splits_comma_or_list():
    """``splits=val,test`` and Hydra's list form ``splits=[val,test]`` name the same splits; a wrong one lists those
    configured (``[val`` passed through as a split's name cost a GPU run its device minutes)."""
    avail = ["train", "val", "test"]
    assert parse_splits("val,test", avail) == ["val", "test"]
    assert parse_splits("[val, test]", avail) == ["val", "test"]
    assert parse_splits("['test']", avail) == ["test"]
    with pytest.raises(ValueError, match="unknown split 'tset'.*train, val, test"):
        parse_splits("[val,tset]", avail)
    with pytest.raises(ValueError, match="no split named"):
        parse_splits("[]", avail)


def test_bad_arguments(tmp_path: Path):
    with pytest.raises(ValueError, match="i/n"):
        parse_shard("3")
    with pytest.raises(ValueError, match="0 <= i < n"):
        parse_shard("2/2")
    with pytest.raises(ValueError, match="unknown data preset"):
        main(["preset=nope"])
    with pytest.raises(ValueError, match="key=value"):
        main(["tiny"])
    with pytest.raises(ValueError, match="unknown split 'nope'"):
        main(["preset=cls_tiny", "splits=[test,nope]", f"cache_dir={tmp_path}"])
    from hydra.utils import instantiate

    ds = instantiate(compose_preset("cls_tiny", ["cache_dir=null"])).make_dataset("train")
    with pytest.raises(ValueError, match="cache directory"):
        pregenerate(ds)


@pytest.mark.slow
def test_parallel_workers(tmp_path: Path):
    args = ARGS + [f"cache_dir={tmp_path}", "workers=2", "splits=train"]
    (st,) = main(args)
    assert st.generated == 3 and st.touches_per_second > 0
    # parallel generation gives the same entries as a serial one
    serial = main(ARGS + [f"cache_dir={tmp_path / 'serial'}", "workers=1", "splits=train"])[0]
    assert serial.generated == 3
    import numpy as np

    from tvrecon.data.cache.store import SampleCache

    a = sorted(p.stem for p in tmp_path.glob("??/*.npz"))
    assert a == sorted(p.stem for p in (tmp_path / "serial").glob("??/*.npz"))
    for key in a:
        x, y = SampleCache(tmp_path).load(key), SampleCache(tmp_path / "serial").load(key)
        assert all(np.array_equal(x[k], y[k]) for k in x)


@pytest.mark.slow
def test_every_split_in_one_pool(tmp_path: Path, monkeypatch, capsys):
    """``workers=2`` over three splits starts one pool, not one per split (each pool start cost ~25 s and a split's
    tail on one worker); every split's entries are written and the run's rate is printed once."""
    from tvrecon.data.generation import pool

    pools = []
    real = pool._pool_generate

    def spy(sets, todo, workers, desc):
        pools.append(sorted({k for k, _ in todo}))
        yield from real(sets, todo, workers, desc)

    monkeypatch.setattr(pool, "_pool_generate", spy)
    stats = main(ARGS + [f"cache_dir={tmp_path}", "workers=2"])
    assert pools == [[0, 1, 2]]
    assert [s.generated for s in stats] == [3, 1, 1] and len(list(tmp_path.glob("*/*.npz"))) == 5
    assert max(s.seconds for s in stats) == pool.combined(stats).seconds > 0
    out = capsys.readouterr().out
    assert "[train, val, test] 5 items generated: 10 touches in" in out and "done" in out


def test_main_names_a_bad_workers_value() -> None:
    """`workers=abc` ended in int()'s message without naming workers."""
    with pytest.raises(ValueError, match="workers must be a whole number"):
        main(["workers=abc"])


def test_default_cache_is_the_projects_whatever_the_working_directory(tmp_path: Path, monkeypatch, capsys) -> None:
    """Run from another folder, generate filled ./data/cache there, not the cache train.py reads."""
    from hydra.utils import instantiate

    from tvrecon.data import generate
    from tvrecon.data.presets import PROJECT_ROOT, default_cache_dir

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PROJECT_ROOT", raising=False)
    expected = (PROJECT_ROOT / "data" / "cache").resolve()
    assert default_cache_dir() == expected and (PROJECT_ROOT / "train.py").is_file()
    dm = instantiate(compose_preset("cls_tiny"))
    assert Path(dm.cache_dir) == expected
    assert instantiate(compose_preset("cls_tiny", ["cache_dir=rel"])).cache_dir == "rel"  # an explicit one is kept
    nothing = lambda sets, **kw: [generate.GenerateStats() for _ in sets]  # noqa: E731
    monkeypatch.setattr(generate, "pregenerate_splits", nothing)  # generate nothing
    generate.main(["preset=cls_tiny", "splits=train", "workers=1"])
    out = capsys.readouterr().out
    assert f"cache: {expected}\n" in out and f"({expected})" in out
    assert not (tmp_path / "data").exists()


def test_compile_key_is_the_press_config_field_the_workers_receive(monkeypatch, tmp_path: Path) -> None:
    """`compile=true|false` is the data-config override `press.compile=...`: the datasets (pickled into the worker
    processes) carry it in their PressConfig; no environment variable is set, and the cache key does not change."""
    import os
    import pickle

    from tvrecon.data import generate
    from tvrecon.data.cache.store import cache_key

    seen = []

    def fake_pregenerate(sets, **kw):
        (ds,) = sets.values()
        worker_copy = pickle.loads(pickle.dumps(ds))  # what a spawned worker receives
        seen.append((worker_copy.press.compile, worker_copy.simulator.compile, cache_key(ds.spec(0))))
        return [generate.GenerateStats()]

    monkeypatch.setattr(generate, "pregenerate_splits", fake_pregenerate)
    monkeypatch.delenv("TVRECON_COMPILE", raising=False)
    base = [*ARGS, f"cache_dir={tmp_path}", "splits=train", "workers=1"]
    generate.main([*base, "compile=true"])
    generate.main([*base, "compile=False"])
    generate.main(base)  # the presets' auto (pregenerate settles it per process: tests/sim/mpm/test_compile_policy.py)
    generate.main([*base, "press.compile=true"])  # the long spelling, as train.py's data.press.compile=true
    generate.main([*base, "compile=AUTO"])
    assert [s[:2] for s in seen] == [(True, True), (False, False), ("auto", "auto"), (True, True), ("auto", "auto")]
    assert len({s[2] for s in seen}) == 1  # one cache key whether compiled or not
    assert "TVRECON_COMPILE" not in os.environ
    with pytest.raises(ValueError, match="compile must be true or false or auto, got 'fast'"):
        generate.main([*ARGS, "compile=fast"])
    with pytest.raises(ValueError, match=r"compile=\.\.\. or press.compile=\.\.\., not both"):
        generate.main([*ARGS, "compile=true", "press.compile=false"])


def test_export_copies_the_presets_entries_and_they_read_as_cached(tmp_path: Path, capsys) -> None:
    from hydra.utils import instantiate

    from tvrecon.data.cache.export import export_entries

    cache, dest = tmp_path / "shared", tmp_path / "export"
    main(ARGS + [f"cache_dir={cache}", "workers=1"])  # every split in the shared cache: 5 entries
    (st,) = main(ARGS + [f"cache_dir={cache}", "workers=1", "splits=train", f"export={dest}"])
    assert "exported to" in capsys.readouterr().out
    assert st.skipped == 3 and len(list(dest.glob("*/*.npz"))) == 3 < len(list(cache.glob("*/*.npz")))  # train's 3
    assert not list(dest.rglob("*.tmp"))
    overrides = [a for a in ARGS if not a.startswith("preset")] + [f"cache_dir={dest}"]
    ds = instantiate(compose_preset("cls_tiny", overrides)).make_dataset("train")
    assert all(ds.raw(i)[1] for i in range(len(ds)))  # every item read from the exported folder, none simulated
    again = export_entries(ds, tmp_path / "again")
    assert again.copied == 3 and again.missing == 0
    assert export_entries(ds, tmp_path / "again").present == 3  # a second export copies nothing
    with pytest.raises(ValueError, match="own cache folder"):
        export_entries(ds, dest)


def test_an_item_that_fails_is_named_and_what_was_done_stays_cached(tmp_path: Path, monkeypatch):
    """An error while generating an item names the split, the item and its object: the same type for Python's own
    exceptions (a FloatingPointError of a press that diverged stays one), ItemFailed for others; the items finished
    before it stay cached and the same command goes on from them."""
    from tvrecon.data.dataset_base import GeneratedDataset
    from tvrecon.data.generation import pool

    args = ARGS + [f"cache_dir={tmp_path}", "workers=1", "splits=train"]
    raw = GeneratedDataset.raw

    class Exploded(Exception):
        def __init__(self, cells: float) -> None:
            super().__init__(f"moved {cells} cells")

    for err, kind in ((FloatingPointError("MPM state exploded"), FloatingPointError), (Exploded(1.5), None)):

        def failing(self, index, err=err):  # noqa: ANN001, ANN202
            if index == 1:
                raise err
            return raw(self, index)

        monkeypatch.setattr(GeneratedDataset, "raw", failing)
        want = kind or pool.ItemFailed
        with pytest.raises(want, match=r"split 'train' item 1 \(\w+, instance \d+\)") as info:
            main(args)
        assert info.value.__cause__ is err and str(err) in str(info.value)
        if kind is None:
            assert str(info.value).startswith("Exploded: ")
    monkeypatch.setattr(GeneratedDataset, "raw", raw)
    (st,) = main(args)
    assert st.skipped == 1 and st.generated == 2  # item 0 was cached before item 1 failed
