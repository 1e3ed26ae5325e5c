"""The contact patch: a touch mapped back to 3D world points (tvrecon.sim.sensor.patch)."""

from __future__ import annotations

import pytest
import torch
import trimesh

from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press.reading import reading_patch
from tvrecon.sim.sensor import SensorConfig
from tvrecon.sim.sensor.patch import contact_patch

N_GRID = 64


@pytest.fixture(scope="module")
def sphere_touches():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.3)
    sensor = SensorConfig(resolution=(16, 16), layers=4, spacing=0.5)
    press = PressConfig(n_grid=N_GRID, record_every=1)
    sim = EIPSimulator(sensor=sensor, press=press)
    positions = torch.tensor([[0.0, 0.0, 0.3], [0.3, 0.0, 0.0]])
    directions = torch.tensor([[0.0, 0.0, -1.0], [-1.0, 0.2, 0.0]])
    readings = sim.press_batch(mesh, positions, directions)
    return mesh, sensor, press, readings


def test_patch_equals_recorded_particles(sphere_touches):
    _, sensor, press, readings = sphere_touches
    HW = 16 * 16
    for r in readings:
        patch = reading_patch(r, sensor, press)
        # the last recorded frame is the reading's step: the patch is the contact layer there, to float round-off
        torch.testing.assert_close(patch.points, r.particles[-1][:HW], atol=1e-6, rtol=0)
        assert patch.mask.sum() > 50


def test_patch_lies_on_the_surface_with_outward_normals(sphere_touches):
    mesh, sensor, press, readings = sphere_touches
    for r in readings:
        patch = reading_patch(r, sensor, press)
        pts = patch.points[patch.mask]
        _, dist, _ = trimesh.proximity.closest_point(mesh, pts.double().numpy())
        assert dist.max() * N_GRID < 0.5  # within half a cell of the true surface
        outward = pts / pts.norm(dim=-1, keepdim=True)  # sphere centred at 0
        assert float((patch.normals[patch.mask] * outward).sum(-1).min()) > 0.9


def test_batched_equals_single(sphere_touches):
    _, sensor, press, readings = sphere_touches
    images = torch.stack([r.image for r in readings])
    pos = torch.stack([r.position for r in readings])
    dirs = torch.stack([r.direction for r in readings])
    batch = contact_patch(images, pos, dirs, sensor, N_GRID)
    assert batch.points.shape == (2, 256, 3) and batch.mask.shape == (2, 256)
    for t, r in enumerate(readings):
        one = reading_patch(r, sensor, press)
        torch.testing.assert_close(batch.points[t], one.points)
        assert torch.equal(batch.mask[t], one.mask)


def test_blank_image_has_no_contact_and_is_the_rest_pad():
    sensor = SensorConfig(resolution=(4, 6), layers=2)
    patch = contact_patch(torch.zeros(3, 4, 6), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)
    assert not patch.mask.any()
    assert torch.allclose(patch.points[:, 2], torch.zeros(24))  # the rest contact plane through the position
    assert torch.allclose(patch.normals, torch.tensor([0.0, 0.0, 1.0]).expand(24, 3))


def test_bad_input_is_named():
    sensor = SensorConfig(resolution=(4, 4), layers=2)
    with pytest.raises(ValueError, match="sensor's resolution"):
        contact_patch(torch.zeros(3, 5, 4), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)
    with pytest.raises(ValueError, match="non-zero"):
        contact_patch(torch.zeros(3, 4, 4), torch.zeros(3), torch.zeros(3), sensor, 32)
    with pytest.raises(ValueError, match=r"image must have shape \(3, H, W\) or \(T, 3, H, W\), got \(4, 4\)"):
        contact_patch(torch.zeros(4, 4), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)
    with pytest.raises(ValueError, match=r"position must have shape \(3,\) or \(T, 3\), got \(2,\)"):
        contact_patch(torch.zeros(3, 4, 4), torch.zeros(2), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)
    with pytest.raises(ValueError, match=r"position and direction must have shape \(2, 3\) like the images"):
        contact_patch(torch.zeros(2, 3, 4, 4), torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)
    bad = torch.zeros(3, 4, 4)
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        contact_patch(bad, torch.zeros(3), torch.tensor([0.0, 0.0, -1.0]), sensor, 32)


def test_default_particle_contact_lays_the_patch_on_the_surface(sphere_touches):
    """The default press's patches lie on the surface to a small fraction of a cell; the grid press of before
    (``contact="grid", threshold_grid=None``: its nodes act up to 1.5 cells before the particles arrive) holds them
    off it. Measured here: mean |distance| 0.023-0.025 cells (particle) against 0.21-0.22 (grid)
    (benchmarks/bench_patch_surface.py: 0.059 against 0.200 over 12 library touches)."""
    mesh, sensor, press, readings = sphere_touches
    grid_press = PressConfig(n_grid=N_GRID, contact="grid", threshold_grid=None)
    grid = EIPSimulator(sensor=sensor, press=grid_press).press_batch(
        mesh, torch.stack([r.position for r in readings]), torch.stack([r.direction for r in readings])
    )
    for r, g in zip(readings, grid):
        means = []
        for reading, cfg in ((r, press), (g, grid_press)):
            patch = reading_patch(reading, sensor, cfg)
            _, dist, _ = trimesh.proximity.closest_point(mesh, patch.points[patch.mask].double().numpy())
            means.append(float(dist.mean()) * N_GRID)
        assert means[0] < 0.1 and means[1] > 2 * means[0]


def test_relative_contact_test_drops_the_rim_that_lies_off_the_surface(sphere_touches):
    """The rim of a contact (pushed in a little, dragged by its neighbours) lies further from the surface than its
    centre: a threshold relative to each touch's deepest push keeps a subset nearer the surface, and no touch empty."""
    mesh, sensor, _, readings = sphere_touches
    images = torch.stack([r.image for r in readings])
    pos = torch.stack([r.position for r in readings])
    dirs = torch.stack([r.direction for r in readings])
    every = contact_patch(images, pos, dirs, sensor, N_GRID)
    inner = contact_patch(images, pos, dirs, sensor, N_GRID, min_push_fraction=0.4)
    torch.testing.assert_close(inner.points, every.points)
    assert not (inner.mask & ~every.mask).any() and (inner.mask.sum(1) > 0).all()
    assert (inner.mask.sum(1) < every.mask.sum(1)).all()
    push = images[:, 2].flatten(1)
    assert torch.equal(inner.mask, push > (0.4 * push.amax(1, keepdim=True)).clamp_min(0.1))

    def mean_dist(p):
        return trimesh.proximity.closest_point(mesh, p.points[p.mask].double().numpy())[1].mean()

    assert mean_dist(inner) < mean_dist(every)
    with pytest.raises(ValueError, match="min_push_fraction"):
        contact_patch(images, pos, dirs, sensor, N_GRID, min_push_fraction=1.0)
