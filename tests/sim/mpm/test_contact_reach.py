"""The particle contact's search reaches only as far as a particle can be pushed this step
(``tvrecon.sim.mpm.contact_reach.speed_reach``): a bound from the step's speeds, at most a cell. Searching that far
instead of a whole cell finds fewer candidates and gives the same press, bit for bit."""

import math

import torch
import trimesh

from tvrecon.sim.mpm import particle_contact
from tvrecon.sim.mpm.contact_reach import speed_reach
from tvrecon.sim.mpm.particle_contact import ITERATIONS
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.press import loop as press_loop
from tvrecon.sim.sensor.elastic_pad import SensorConfig


def test_speed_reach_grows_with_the_speed_and_stops_at_a_cell():
    dx, dt, cap = 1.0 / 64, 1e-3, 0.05 / 64 / 1e-3  # the push-out cap: 0.05 cells a step
    at = lambda s, mu=0.0: float(speed_reach(torch.tensor(s), dt, dx, ITERATIONS, cap, mu))  # noqa: E731
    still = at(0.0)
    assert math.isclose(still, (3 * cap * dt) * (1 + 1e-3) + 1e-3 * dx, rel_tol=1e-5), "at rest: the push-out alone"
    slow = 0.02 * dx / dt  # a node moving 0.02 cells a step (a pressing pad)
    # three passes: the speeds the later passes may see, s -> s + (c + s), twice; sqrt(3): a component to a speed
    s = math.sqrt(3) * slow
    assert math.isclose(at(slow), (4 * s + 3 * cap) * dt * (1 + 1e-3) + 1e-3 * dx, rel_tol=1e-5)
    assert still < at(slow) < at(slow, mu=0.5) < dx, "friction's tangential change counts too"
    assert at(1.0 * dx / dt) == dx and at(math.inf) == dx and at(math.nan) == dx, "never beyond a cell; NaN: a cell"


def _press(monkeypatch, whole_cell: bool):
    """Two eager touches of a sphere (particle contact), the candidates of every step counted."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    sensor = SensorConfig(resolution=(12, 12), layers=4)
    press = PressConfig(n_grid=48, contact="particle")
    counts: list[int] = []
    near = particle_contact.near_surface

    def counted(*args, **kw):  # noqa: ANN002, ANN003, ANN202
        out = near(*args, **kw)
        counts.append(out[0].numel())
        return out

    monkeypatch.setattr(particle_contact, "near_surface", counted)
    if whole_cell:  # the search as it was: a whole cell every step
        monkeypatch.setattr(particle_contact, "contact_search_reach", lambda gv, s, h, a, dt, dx, f: dx)
    monkeypatch.setattr(press_loop, "FREE_FLIGHT", False)  # every step a full one
    out = EIPSimulator(sensor, press).press_batch(mesh, [[0.0, 0.0, 0.3], [0.3, 0.0, 0.0]], [[0, 0, -1], [-1, 0, 0]])
    monkeypatch.undo()
    return out, counts


def test_the_speed_bound_finds_fewer_candidates_and_presses_the_same(monkeypatch):
    cell, n_cell = _press(monkeypatch, whole_cell=True)
    bound, n_bound = _press(monkeypatch, whole_cell=False)
    assert len(n_cell) == len(n_bound) and sum(n_bound) < 0.8 * sum(n_cell), (sum(n_bound), sum(n_cell))
    for a, b in zip(cell, bound):
        assert a.contact and a.image.abs().max() > 0.1 and a.steps == b.steps
        for k in ("image", "force", "force_field", "position"):
            assert torch.equal(getattr(a, k), getattr(b, k)), k
