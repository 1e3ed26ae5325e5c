"""The particle contact's kept candidate list (``MeshStackCache`` with a skin, ``MLSMPM.contact_skin``): a press that
reuses the list between searches gives the same readings, bit for bit on the CPU, as one that searches every step,
with a fraction of the searches (each a host sync); a list is dropped when the particles moved past the skin."""

import warnings

import pytest
import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.bodies.colliders import MeshCollider
from tvrecon.sim.mpm.particle_contact import MeshStackCache, near_surface, scene_slices
from tvrecon.sim.mpm.solver import MLSMPM


def _press(skin: float, monkeypatch: pytest.MonkeyPatch) -> tuple[list, int, int]:
    monkeypatch.setattr(MLSMPM, "contact_skin", skin)
    searches: list[int] = []
    step = MLSMPM.step

    def counted(self, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
        out = step(self, *a, **k)
        searches[:] = [self._mesh_stack.searches]
        return out

    monkeypatch.setattr(MLSMPM, "step", counted)
    sim = EIPSimulator(SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0))
    mesh = trimesh.creation.box(extents=(0.2, 0.15, 0.12))
    pos = torch.tensor([[0.0, 0.0, 0.06], [0.03, 0.02, 0.06], [0.1, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [0.2, 0.1, -1.0], [-1.0, 0.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        readings = sim.press_batch(mesh, pos, dirs)
    return readings, searches[0], max(int(r.steps) for r in readings)


def test_kept_list_gives_the_same_press_with_fewer_searches(monkeypatch):
    every, n_every, steps = _press(0.0, monkeypatch)
    kept, n_kept, steps_kept = _press(0.5, monkeypatch)
    assert steps_kept == steps > 10 and n_every >= steps
    assert n_kept <= n_every / 3, (n_kept, n_every)
    for a, b in zip(every, kept):
        assert a.steps == b.steps and a.contact and b.contact
        assert torch.equal(a.image, b.image)
        assert torch.equal(a.force, b.force)
        assert torch.equal(a.force_field, b.force_field)


def _sphere_cache(skin: float) -> tuple[MeshStackCache, list[MeshCollider]]:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1).apply_translation([0.5, 0.5, 0.5])
    return MeshStackCache(skin=skin), [MeshCollider(sphere, n_grid=64)]


def test_list_is_searched_again_when_the_particles_moved_past_the_skin():
    dx = 1 / 64
    cache, cols = _sphere_cache(0.5 * dx)
    x = torch.rand(2000, 3, dtype=torch.float32) * 0.4 + 0.3
    slices = scene_slices(None, 1, None)
    first = near_surface(x, cols, slices, dx, None, cache)
    assert cache.searches == 1
    assert cache.candidates(x, None, dx) is None  # no drift read yet: search
    cache.set_drift(x, float(cache.drift_of(x)))
    again = near_surface(x, cols, slices, dx, None, cache)
    assert cache.searches == 1 and torch.equal(again[0], first[0]) and torch.equal(again[2], first[2])
    # moved within the skin: the list is kept, and it still holds every particle within reach
    y = x + torch.tensor([0.4 * dx, 0.0, 0.0])
    cache.set_drift(y, float(cache.drift_of(y)))
    kept = near_surface(y, cols, slices, dx, None, cache)
    fresh = near_surface(y, cols, slices, dx, None, MeshStackCache())
    assert cache.searches == 1
    close = kept[0][kept[2] < dx]
    assert torch.equal(close, fresh[0][fresh[2] < dx])
    # past the skin (or an unread drift, or a NaN): a fresh search
    z = x + torch.tensor([0.6 * dx, 0.0, 0.0])
    cache.set_drift(z, float(cache.drift_of(z)))
    near_surface(z, cols, slices, dx, None, cache)
    assert cache.searches == 2
    cache.set_drift(z, float("nan"))
    near_surface(z, cols, slices, dx, None, cache)
    assert cache.searches == 3


def test_no_skin_keeps_nothing():
    cache, cols = _sphere_cache(0.0)
    x = torch.rand(500, 3) * 0.4 + 0.3
    near_surface(x, cols, scene_slices(None, 1, None), 1 / 64, None, cache)
    assert cache.drift_of(x) is None
