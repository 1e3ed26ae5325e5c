"""Touch set-up in worker processes (``EIPSimulator(setup_processes=N)``): the same placements and readings as the
thread path, bit for bit; a touch's error reaches the caller; a bad count is refused; the simulator still pickles."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.bodies.colliders import MeshCollider
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig

SENSOR = SensorConfig(resolution=(8, 8), layers=3)
PRESS = PressConfig(n_grid=32, speed_fraction=0.25)


def _touches() -> tuple[trimesh.Trimesh, torch.Tensor, torch.Tensor]:
    mesh = trimesh.creation.box(extents=(0.5, 0.4, 0.3))
    dirs = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, -1.0], [0.0, 1.0, 0.0]])
    pos = -0.2 * torch.nn.functional.normalize(dirs, dim=1)  # a point on the side each direction presses
    return mesh, pos, dirs


@pytest.fixture(scope="module")
def pooled():
    sim = EIPSimulator(SENSOR, PRESS, setup_processes=2)
    yield sim
    sim.close()


def test_processes_give_the_same_placements_and_readings(pooled: EIPSimulator) -> None:
    mesh, pos, dirs = _touches()
    threads = EIPSimulator(SENSOR, PRESS, setup_threads=1)
    for a, b in zip(threads.place_batch(mesh, pos, dirs), pooled.place_batch(mesh, pos, dirs), strict=True):
        for name in ("origin", "R", "direction"):
            np.testing.assert_array_equal(getattr(a, name).numpy(), getattr(b, name).numpy())
        assert a.reachable == b.reachable and (a.collider is None) == (b.collider is None)
        if a.collider is not None:
            assert a.collider.n_samples == b.collider.n_samples and a.collider.dims == b.collider.dims
            for table in ("node_sdf", "node_normal", "lo", "hi", "lo_index"):
                assert torch.equal(getattr(a.collider, table), getattr(b.collider, table)), table
    ra, rb = threads.press_batch(mesh, pos, dirs, depth=1.0), pooled.press_batch(mesh, pos, dirs, depth=1.0)
    assert sum(r.contact for r in ra) >= 3  # the touches feel the box
    for a, b in zip(ra, rb, strict=True):
        assert a.steps == b.steps and a.contact == b.contact
        assert torch.equal(a.image, b.image)


def test_a_touch_error_reaches_the_caller(pooled: EIPSimulator) -> None:
    mesh, pos, dirs = _touches()
    dirs = dirs.clone()
    dirs[1] = -dirs[1]  # presses outwards from inside the box's side: the pad would start inside the object
    with pytest.raises(ValueError, match="the pad would start inside the object"):
        pooled.place_batch(mesh, pos, dirs)
    assert len(pooled.place_batch(mesh, pos[:2], _touches()[2][:2])) == 2  # the pool still works afterwards


def test_simulator_pickles_without_its_workers(pooled: EIPSimulator) -> None:
    mesh, pos, dirs = _touches()
    pooled.place_batch(mesh, pos[:2], dirs[:2])  # the pool has started
    copy = pickle.loads(pickle.dumps(pooled))
    assert copy._setup_pool is None and copy.setup_processes == 2


def test_collider_to_device_copies_the_tables() -> None:
    collider = MeshCollider(trimesh.creation.icosphere(radius=0.2).apply_translation([0.5, 0.5, 0.5]), n_grid=16)
    assert collider.to("cpu") is collider
    moved = collider.to("meta")  # another device, available everywhere
    assert moved is not collider and moved.node_sdf.device.type == "meta" and moved.lo.device.type == "meta"
    assert collider.node_sdf.device.type == "cpu" and moved.dims == collider.dims


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2"])
def test_bad_process_count(bad) -> None:
    with pytest.raises(ValueError, match="setup_processes must be a whole number"):
        EIPSimulator(SENSOR, PRESS, setup_processes=bad)
