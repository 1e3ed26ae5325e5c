"""Touch set-up in threads (``EIPSimulator(setup_threads=...)``): the placements and the readings do not depend on
the thread count, and a bad count is refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

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
