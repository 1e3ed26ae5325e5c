"""Per-taxel force field: sums to the recorded total force, zero off the contact, normal pushes into the pad."""

from __future__ import annotations

import pytest
import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.sensor.forces import column_force_field, field_total, normal_shear

SPHERE = trimesh.creation.icosphere(subdivisions=3, radius=0.1)  # 3.2 cells: the contact covers part of the pad


pytestmark = pytest.mark.usefixtures("one_thread")  # see tests/conftest.py


@pytest.fixture(scope="module")
def readings():
    """A 12x12x3 pad (11 cells across) pressed 1 cell onto a small sphere, from above and (batched) from the side."""
    sim = EIPSimulator(
        SensorConfig(resolution=(12, 12), layers=3, spacing=1.0), PressConfig(n_grid=32, speed_fraction=0.25)
    )
    return sim.press_batch(
        [SPHERE, SPHERE], [[0.0, 0.0, 0.1], [0.1, 0.0, 0.0]], [[0, 0, -1.0], [-1.0, 0, 0]], depth=1.0
    )


def test_field_sums_to_the_recorded_force(readings) -> None:
    for r in readings:
        assert r.contact and r.force_field.shape == (12, 12, 3) and r.force_field.dtype == torch.float32
        total = field_total(r.force_field, r.frame)
        err = float((total - r.force).norm() / r.force.norm())
        assert err < 0.01, err  # measured 1e-7: the node forces are shared out exactly
        # in the sensor frame the total is R^T force
        torch.testing.assert_close(field_total(r.force_field), r.frame.T @ r.force, rtol=1e-4, atol=1e-7)


def test_field_is_zero_off_the_contact_and_normal_positive_under_it(readings) -> None:
    r = readings[0]
    normal, shear = normal_shear(r.force_field)
    assert normal.shape == (12, 12) and shear.shape == (12, 12, 2)
    # the contact: taxels within the Hertz contact radius sqrt(R d) (R = 3.2 cells, d ~ 1: 1.8 cells). The pad is
    # also pushed in around it (0.29 cells at 2.1 cells from the centre), where the particle contact (the default)
    # exerts no force: an image threshold would mark those taxels as touched
    i, j = torch.meshgrid(torch.arange(12.0), torch.arange(12.0), indexing="ij")
    radius = ((i - 5.5) ** 2 + (j - 5.5) ** 2).sqrt()  # taxel centres' distance from the press axis, cells
    under = radius < (0.1 * 32 * r.depth) ** 0.5
    assert int(under.sum()) >= 4
    assert bool((normal[under] > 0).all())
    # beyond the contact plus the transfer stencil (1.5 cells) nothing acts
    far = radius > 4.0
    assert float(r.force_field[far].abs().max()) == 0.0
    # a centred sphere press: the normal force dominates and peaks at the centre
    assert float(shear.sum((0, 1)).norm()) < 0.01 * float(normal.sum())
    assert float(normal[5:7, 5:7].min()) == pytest.approx(float(normal.max()), rel=0.02)


def test_no_contact_gives_a_zero_field() -> None:
    sim = EIPSimulator(SensorConfig(resolution=(6, 6), layers=3), PressConfig(n_grid=32, speed_fraction=0.25))
    r = sim.press(SPHERE, [0.0, 0.0, 0.1], [0, 0, -1.0], gap=4.0, max_steps=5, threshold=None)
    assert not r.contact
    assert float(r.force_field.abs().max()) == 0.0


def test_column_field_is_batched_and_checks_its_input() -> None:
    f = torch.randn(2, 5, 3 * 4 * 6, 3, dtype=torch.float64)
    field = column_force_field(f, (4, 6), 3)
    assert field.shape == (2, 5, 4, 6, 3) and field.dtype == torch.float64
    torch.testing.assert_close(field_total(field), f.sum(-2))
    torch.testing.assert_close(field[1, 2], column_force_field(f[1, 2], (4, 6), 3))
    with pytest.raises(ValueError, match=r"particle_force must have P = layers \* H \* W = 48"):
        column_force_field(f, (4, 6), 2)
    bad = f.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        column_force_field(bad, (4, 6), 3)
    with pytest.raises(ValueError, match=r"field must have shape \(\.\.\., H, W, 3\), got \(4, 6\)"):
        normal_shear(torch.zeros(4, 6))
    with pytest.raises(ValueError, match=r"frame must have shape \(\.\.\., 3, 3\), got \(2, 2\)"):
        field_total(field, torch.eye(2))
