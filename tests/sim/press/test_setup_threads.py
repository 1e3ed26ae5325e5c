"""Touch set-up in threads (``EIPSimulator(setup_threads=...)``) or processes (``setup_processes=N``): the placements
and the readings do not depend on the thread count, processes give the thread path's bit for bit, a touch's error
reaches the caller, a bad count is refused, and the simulator still pickles."""

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


def test_threads_give_the_same_placements_and_readings() -> None:
    mesh, pos, dirs = _touches()
    one = EIPSimulator(SENSOR, PRESS, setup_threads=1)
    three = EIPSimulator(SENSOR, PRESS, setup_threads=3)
    assert one._setup_workers(4) == 1 and three._setup_workers(4) == 3 and three._setup_workers(2) == 2
    for a, b in zip(one.place_batch(mesh, pos, dirs), three.place_batch(mesh, pos, dirs), strict=True):
        np.testing.assert_array_equal(a.origin.numpy(), b.origin.numpy())
        np.testing.assert_array_equal(a.R.numpy(), b.R.numpy())
        assert (a.collider is None) == (b.collider is None)
        if a.collider is not None:
            np.testing.assert_array_equal(a.collider.node_sdf.cpu().numpy(), b.collider.node_sdf.cpu().numpy())
    ra, rb = one.press_batch(mesh, pos, dirs, depth=1.0), three.press_batch(mesh, pos, dirs, depth=1.0)
    assert sum(r.contact for r in ra) >= 3  # the touches feel the box
    for a, b in zip(ra, rb, strict=True):
        assert a.steps == b.steps and a.contact == b.contact
        torch.testing.assert_close(a.image, b.image, rtol=0, atol=0)


def test_default_thread_count_follows_the_device() -> None:
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert EIPSimulator(SENSOR, PRESS)._setup_workers(10) == 1  # generate's workers: one thread each
        torch.set_num_threads(2)
        assert EIPSimulator(SENSOR, PRESS)._setup_workers(10) == 2
        assert EIPSimulator(SENSOR, PRESS)._setup_workers(1) == 1
    finally:
        torch.set_num_threads(saved)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_thread_count(bad) -> None:
    with pytest.raises(ValueError, match="setup_threads must be a positive int"):
        EIPSimulator(SENSOR, PRESS, setup_threads=bad)


# ---------------------------------------------------------------------------------------------- processes
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


def test_a_dead_worker_is_reported_and_the_next_call_starts_new_ones() -> None:
    mesh, pos, dirs = _touches()
    sim = EIPSimulator(SENSOR, PRESS, setup_processes=2)
    try:
        expected = sim.place_batch(mesh, pos, dirs)
        for proc in list(sim._setup_pool._pool._processes.values()):
            proc.kill()  # as the out-of-memory killer would
            proc.join()
        with pytest.raises(RuntimeError, match="set-up worker process died"):
            sim.place_batch(mesh, pos, dirs)
        again = sim.place_batch(mesh, pos, dirs)
        assert all(torch.equal(a.origin, b.origin) for a, b in zip(expected, again, strict=True))
    finally:
        sim.close()


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
