"""Generated datasets: sample shapes, determinism (also across a cache hit), invalidation, corruption recovery."""

import logging
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.data.cache.store import cache_key
from tvrecon.data.shapes import ObjectLibrary
from tvrecon.data.task_datasets import ReconstructionDataset, TactileClassificationDataset
from tvrecon.data.touches.policies import Touches
from tvrecon.sim.sensor.elastic_pad import SensorConfig
from tvrecon.utils.config_utils import coerce_config

# tiny simulation: 8x8 pad, 3 layers, 32^3 grid, short fast presses, one press strength
PRESS = {"n_grid": 32, "max_depth": 1.5, "gap": 0.5, "speed_fraction": 0.2}
SIM = {
    "sensor": {"resolution": (8, 8), "layers": 3},
    "press": PRESS,
    "touch": {"strengths": [{"threshold": 0.05}], "cone_deg": 10.0},
}

_LIB = ObjectLibrary()


def recon(cache_dir, **over) -> ReconstructionDataset:
    args = dict(
        num_samples=3,
        classes=["cube", "bottle"],
        min_touches=1,
        max_touches=2,
        num_points=64,
        tactile_size=12,
        render={"image_size": 32},
        cache_dir=cache_dir,
        library=_LIB,
        **SIM,
    )
    args.update(over)
    return ReconstructionDataset(**args)


def classif(cache_dir, **over) -> TactileClassificationDataset:
    args = dict(
        num_objects=2,
        classes=["cube", "torus"],
        touches_per_object=3,
        num_touches=2,
        tactile_size=12,
        cache_dir=cache_dir,
        library=_LIB,
        **SIM,
    )
    args.update(over)
    return TactileClassificationDataset(**args)


def assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype, k
        assert torch.equal(a[k], b[k]), k


@pytest.fixture(scope="module")
def recon_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("recon_cache")


def test_reconstruction_sample_shapes(recon_cache: Path):
    ds = recon(recon_cache)
    s = ds[1]
    M = 2
    assert s["image"].shape == (3, 32, 32) and s["image"].dtype == torch.float32
    assert 0.0 <= float(s["image"].min()) and float(s["image"].max()) <= 1.0
    assert s["K"].shape == (3, 3) and s["RT"].shape == (3, 4)
    assert s["tactile"].shape == (M, 3, 12, 12) and s["tactile"].dtype == torch.float32
    assert s["positions"].shape == (M, 3) and s["directions"].shape == (M, 3)
    assert s["touch_mask"].shape == (M,) and s["touch_mask"].dtype == torch.bool
    assert s["points"].shape == (64, 3) and s["normals"].shape == (64, 3)
    assert s["label"].dtype == torch.int64 and s["label"].ndim == 0
    cls, _ = ds.object_of(1)
    assert cls == "bottle" and int(s["label"]) == _LIB.classes.index("bottle")
    T = ds.num_touches(1)
    assert s["touch_mask"].tolist() == [True] * T + [False] * (M - T)
    assert torch.all(s["tactile"][T:] == 0) and torch.all(s["positions"][T:] == 0)
    assert torch.allclose(s["directions"][:T].norm(dim=-1), torch.ones(T), atol=1e-5)
    # GT points lie on the object's surface, normals are unit
    mesh = ds.mesh(1)
    _, dist, _ = trimesh.proximity.closest_point(mesh, s["points"].double().numpy())
    assert dist.max() < 1e-4
    assert torch.allclose(s["normals"].norm(dim=-1), torch.ones(64), atol=1e-4)


def test_raw_cache_keeps_sensor_resolution_and_contact_is_visible(recon_cache: Path):
    ds = recon(recon_cache)
    raw, _ = ds.raw(0)
    assert raw["tactile"].shape == (2, 3, 8, 8)  # raw pad resolution on disk, resized on load
    assert raw["contact"].any(), "no touch reached the object"
    for t in np.flatnonzero(raw["contact"]):
        assert np.abs(raw["tactile"][t]).max() > 0, "a touch with contact left a blank tactile image"
    # the model-resolution image is the kornia resize of the raw one divided by tactile_scale
    ds2 = recon(recon_cache, tactile_scale=2.0)
    T = ds.num_touches(0)
    assert torch.allclose(ds2[0]["tactile"][:T] * 2.0, ds[0]["tactile"][:T], atol=1e-6)


@pytest.mark.slow
def test_determinism_fresh_caches_and_cache_hit(tmp_path: Path):
    a = recon(tmp_path / "a")
    assert not a.is_cached(2)
    s_miss = a[2]  # generated and stored
    assert a.raw(2)[1]
    s_hit = a[2]  # read back from the cache
    assert_same(s_miss, s_hit)
    assert_same(recon(tmp_path / "b")[2], s_hit)  # another process / fresh cache: same bits
    assert_same(recon(None)[2], s_hit)  # cache disabled: same bits as well


def test_seed_split_and_index_change_the_sample(recon_cache: Path):
    ds = recon(recon_cache)
    assert not torch.equal(ds[0]["RT"], ds[2]["RT"])
    assert cache_key(ds.spec(0)) != cache_key(recon(recon_cache, seed=1).spec(0))
    assert cache_key(ds.spec(0)) != cache_key(recon(recon_cache, split="test").spec(0))
    assert ds.seeds(0) != recon(recon_cache, seed=1).seeds(0)


def test_config_change_invalidates_but_load_options_do_not(recon_cache: Path):
    ds = recon(recon_cache)
    ds.raw(0)
    key = cache_key(ds.spec(0))
    for changed in (
        recon(recon_cache, sensor={"resolution": (8, 8), "layers": 3, "E": 4.0}),
        recon(recon_cache, press={**PRESS, "max_depth": 2.0}),
        recon(recon_cache, touch={"strengths": [{"threshold": 0.1}]}),
        recon(recon_cache, render={"image_size": 30}),
        recon(recon_cache, num_points=65),
        recon(recon_cache, max_touches=3),
        recon(recon_cache, library=ObjectLibrary(deform=0.05)),
    ):
        assert cache_key(changed.spec(0)) != key
    for same in (
        recon(recon_cache, tactile_size=16),
        recon(recon_cache, num_touches=1),
        recon(recon_cache, min_touches=2),
    ):
        assert cache_key(same.spec(0)) == key
        assert same.is_cached(0)
    assert recon(recon_cache, num_touches=1)[0]["touch_mask"].tolist() == [True, False]


def test_variable_touch_count_in_range(recon_cache: Path):
    ds = recon(recon_cache, num_samples=40, min_touches=1, max_touches=3)
    counts = {ds.num_touches(i) for i in range(40)}
    assert counts == {1, 2, 3}


@pytest.mark.slow
def test_corrupt_entry_is_regenerated_with_warning(tmp_path: Path, caplog):
    ds = recon(tmp_path)
    before = ds[0]
    path = ds.cache.path(cache_key(ds.spec(0)))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 3])
    with caplog.at_level(logging.WARNING):
        after = ds[0]
    assert str(path) in caplog.text
    assert_same(before, after)
    assert ds.raw(0)[1]  # healthy again
    assert [p.name for p in tmp_path.rglob("*") if p.is_file() and not p.name.endswith(".npz")] == []


def test_unplaceable_touch_is_redrawn(recon_cache: Path):
    ds = recon(recon_cache)
    mesh = ds.mesh(0)  # a cube: pressing from inside outwards cannot be placed
    good = Touches(
        positions=torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5]]),
        directions=torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]),  # second one points out of the object
        normals=torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]),
        strengths=[{"threshold": 0.05}, {"threshold": 0.05}],
    )
    with pytest.raises(ValueError):
        ds.simulator.press(mesh, good.positions[1], good.directions[1], max_steps=1)
    fixed = ds._placeable_touches(mesh, good, seed=5)
    assert torch.equal(fixed.positions[0], good.positions[0])  # accepted touches are kept
    assert not torch.equal(fixed.directions[1], good.directions[1])  # the rejected one is re-drawn
    again = ds._placeable_touches(mesh, good, seed=5)
    assert torch.equal(again.positions, fixed.positions)  # deterministic
    ds.simulator.press(mesh, fixed.positions[1], fixed.directions[1], max_steps=1)


def test_memory_cache_reads_each_entry_from_disk_once(recon_cache: Path, monkeypatch):
    ds, plain = recon(recon_cache, memory_cache=True), recon(recon_cache)
    reads = []
    original = ds.cache.get_or_create
    monkeypatch.setattr(ds.cache, "get_or_create", lambda *a, **k: reads.append(1) or original(*a, **k))
    first = ds[0]
    assert_same(first, plain[0])
    for _ in range(3):
        assert_same(ds[0], first)
        assert ds.raw(0)[1]
    assert len(reads) == 1
    ds.raw(0)[0]["tactile"] = None  # callers may edit their copy of the entry: the kept one is unchanged
    assert_same(ds[0], first)


def test_dataset_pickles_without_simulator(recon_cache: Path):
    ds = recon(recon_cache)
    assert ds.simulator is ds.simulator  # built once per process
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._simulator is None
    assert_same(clone[0], ds[0])


def test_worker_process_sets_up_touches_in_its_thread_budget(recon_cache: Path, monkeypatch):
    """In a pool or dataloader worker the simulator's set-up threads follow torch's thread count (1 there), also on a
    GPU, where the simulator's own default is every core of the host: 16 workers must not start 16 threads each."""
    import multiprocessing

    assert recon(recon_cache, sim_device="meta").simulator.setup_threads is None  # the main process: the default
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: object())  # as in a spawned worker
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        sim = recon(recon_cache, sim_device="meta").simulator
        assert sim.setup_threads == 1 and sim._setup_workers(10) == 1
    finally:
        torch.set_num_threads(saved)


@pytest.mark.slow
def test_classification_sample_and_shared_cache(tmp_path: Path):
    ds = classif(tmp_path)
    s = ds[1]
    assert s["tactile"].shape == (2, 3, 12, 12) and s["tactile"].dtype == torch.float32
    assert s["touch_mask"].tolist() == [True, True]
    assert s["positions"].shape == (2, 3) and s["directions"].shape == (2, 3)
    assert int(s["label"]) == _LIB.classes.index("torus") and s["label"].dtype == torch.int64
    sel = ds.touch_indices(1)
    assert len(set(sel.tolist())) == 2  # different touches (press directions) of the same object
    raw, hit = ds.raw(1)
    assert hit
    assert torch.equal(s["positions"], torch.from_numpy(raw["positions"][sel]))
    one = classif(tmp_path, num_touches=3)  # another N reuses the cached touches
    assert one.raw(1)[1]
    assert one[1]["tactile"].shape == (3, 3, 12, 12)
    assert_same(classif(tmp_path / "other")[1], s)


def test_bad_arguments_raise_clear_errors(tmp_path: Path):
    with pytest.raises(ValueError, match="min_touches <= max_touches"):
        recon(tmp_path, min_touches=3, max_touches=2)
    with pytest.raises(ValueError, match="num_touches must be None or in"):
        recon(tmp_path, num_touches=3)
    with pytest.raises(ValueError, match="not in the object library"):
        recon(tmp_path, classes=["cube", "unicorn"])
    with pytest.raises(ValueError, match=r"unknown SensorConfig option\(s\) \['resolutoin'\]"):
        recon(tmp_path, sensor={"resolutoin": (8, 8)})
    with pytest.raises(ValueError, match="num_touches <= touches_per_object"):
        classif(tmp_path, num_touches=4)
    with pytest.raises(IndexError, match="out of range"):
        recon(tmp_path)[3]
    assert coerce_config(SensorConfig, {"resolution": [8, 8]}).resolution == (8, 8)


def test_reconstruction_sample_exposes_contact_patches(recon_cache: Path):
    ds = recon(recon_cache)
    s = ds[1]
    M, Hs, Ws = ds.max_touches, *ds.sensor.resolution
    T = ds.num_touches(1)
    assert s["patch_points"].shape == (M, Hs * Ws, 3) and s["patch_normals"].shape == (M, Hs * Ws, 3)
    assert s["patch_mask"].shape == (M, Hs * Ws) and s["patch_mask"].dtype == torch.bool
    assert not s["patch_mask"][T:].any()  # padded touches have no patch
    assert s["patch_mask"][:T].any()
    # pushed-in contact-layer points lie on the object's surface (within a cell at this tiny grid)
    pts = s["patch_points"][s["patch_mask"]].double().numpy()
    _, dist, _ = trimesh.proximity.closest_point(ds.mesh(1), pts)
    assert dist.max() * ds.press.n_grid / ds.press.domain_size < 1.0


def test_patch_min_push_keeps_the_deeper_pushed_points_of_the_same_cache_entry(recon_cache: Path):
    """A stricter contact test drops the pad's rim (points barely pushed in) from the patch, on load: the same cached
    entry (no regeneration), the points' mask re-derived from the cached push depth, a subset of the default mask."""
    base = recon(recon_cache)
    a = base[1]
    raw, _ = base.raw(1)
    push = torch.from_numpy(raw["tactile"][: base.num_touches(1), 2]).flatten(1)  # (T, Hs*Ws) cells
    threshold = float(push[push > 0.1].median())  # half of the default patch's points are pushed in deeper
    strict = recon(recon_cache, patch_min_push=threshold)
    assert cache_key(base.spec(1)) == cache_key(strict.spec(1)) and strict.is_cached(1)
    b = strict[1]
    assert torch.equal(a["patch_points"], b["patch_points"])
    assert torch.equal(b["patch_mask"][: push.shape[0]], push > threshold)
    assert not (b["patch_mask"] & ~a["patch_mask"]).any()  # a subset
    assert 0 < b["patch_mask"].sum() < a["patch_mask"].sum()
    relative = recon(recon_cache, patch_min_push_fraction=0.5)[1]["patch_mask"][: push.shape[0]]
    assert torch.equal(relative, push > (0.5 * push.amax(1, keepdim=True)).clamp_min(0.1))
    with pytest.raises(ValueError, match="patch_min_push"):
        recon(recon_cache, patch_min_push=float("nan"))
    with pytest.raises(ValueError, match="patch_min_push_fraction"):
        recon(recon_cache, patch_min_push_fraction=-0.1)


def test_int_and_float_sensor_numbers_give_one_cache_key() -> None:
    """`sensor.E=3` and `sensor.E=3.0` gave different cache keys (identical data regenerated)."""
    from tvrecon.data.cache.store import cache_key
    from tvrecon.sim.sensor import SensorConfig
    from tvrecon.utils.config_utils import coerce_config

    a = coerce_config(SensorConfig, {"E": 3})
    b = coerce_config(SensorConfig, {"E": 3.0})
    assert isinstance(a.E, float)
    assert cache_key({"sensor": a}) == cache_key({"sensor": b})


def test_cached_label_follows_the_class_name_when_the_class_list_changes(tmp_path: Path) -> None:
    """entries cached before a class was added kept their old integer label (now another class)."""
    before = ObjectLibrary(classes=["cube", "torus"])
    after = ObjectLibrary(classes=["bottle", "cube", "torus"])  # a class added in front: every label shifts by one
    ds = classif(tmp_path, num_objects=1, classes=["torus"], touches_per_object=1, num_touches=1, library=before)
    assert int(ds[0]["label"]) == before.label("torus") == 1
    ds2 = classif(tmp_path, num_objects=1, classes=["torus"], touches_per_object=1, num_touches=1, library=after)
    assert ds2.spec(0) == ds.spec(0)  # same entry: reconstruction/classification cache keys are unchanged
    raw, hit = ds2.raw(0)
    assert hit and int(raw["label"]) == after.label("torus") == 2
    assert int(ds2[0]["label"]) == 2
