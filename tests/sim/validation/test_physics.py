"""Fast physics checks of the solver (the full benchmark is benchmarks/physics/bench_physics.py).

Tiny pads on coarse grids: each test asserts a physical property with a tolerance the current solver meets. The
Hertz bands are broad on purpose: today the contact acts on grid nodes, so exponents depend on where the sphere's
apex sits between node planes (docs/validation/physics.md); the tests pin what holds at every offset.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig
from tvrecon.sim.validation.physics_checks import (
    free_oscillation,
    free_slab_impact,
    hertz_force,
    hertz_radius,
    loglog_slope,
    slab_press,
    winkler_force,
)

TINY = {"n_grid": 32, "width": 8.0, "thick": 2.0, "R": 4.0, "max_depth": 1.5}


def test_theory_curves_have_their_exponents():
    d = np.linspace(0.5, 3.0, 20)
    assert loglog_slope(d, hertz_force(3.0, 0.25, 12.0, d), 0.5, 3.0) == pytest.approx(1.5, abs=1e-9)
    assert loglog_slope(d, hertz_radius(12.0, d), 0.5, 3.0) == pytest.approx(0.5, abs=1e-9)
    assert loglog_slope(d, winkler_force(3.0, 0.25, 12.0, 6.0, d), 0.5, 3.0) == pytest.approx(2.0, abs=1e-9)
    # F = 4/3 E* sqrt(R) d^1.5 at one point, and the thin layer is stiffer than the half-space when a >> h
    assert float(hertz_force(3.0, 0.25, 4.0, 1.0)) == pytest.approx(4.0 / 3.0 * 3.2 * 2.0)
    assert float(winkler_force(3.0, 0.25, 12.0, 0.5, 2.0)) > float(hertz_force(3.0, 0.25, 12.0, 2.0))


@pytest.mark.parametrize("offset", [0.0, 0.25, 0.5, 0.75])
def test_hertz_press_force_grows_with_depth(offset):
    r = slab_press((offset,), **TINY)
    d, f, a = r.depth[0], r.force[0], r.radius[0]
    dx = r.dx
    first = d[np.argmax(f > 0)]
    # the grid contact starts before the particles reach the sphere, by less than the 1.5-cell stencil reach
    assert -1.6 < first <= 0.0
    inside = d > 0.1
    fi = f[inside]
    # the pad is pushed harder the deeper it goes (per step noise below 2% of the final force)
    assert np.all(np.diff(fi) > -0.02 * fi[-1])
    assert fi[-1] > 3 * fi[0] > 0
    # a broad band around Hertz's 1.5 / the thin layer's 2 at every apex offset (see docs/validation/physics.md)
    assert 1.0 < loglog_slope(d, f, 0.75, TINY["max_depth"]) < 2.6
    # the 2-cell layer bonded to the hand lies between a half-space (Hertz) and the thin-layer limit (Winkler,
    # 3.25x Hertz here); measured 1.6-3.4x Hertz depending on the offset
    f_end = float(np.interp(1.5, d, f))
    assert float(hertz_force(3.0, 0.25, TINY["R"] * dx, 1.5 * dx)) < f_end
    assert f_end < 1.2 * float(winkler_force(3.0, 0.25, TINY["R"] * dx, TINY["thick"] * dx, 1.5 * dx))
    assert 0.7 < float(np.interp(1.5, d, a)) / float(hertz_radius(TINY["R"], 1.5)) < 1.6


def test_force_scales_linearly_with_E_and_grows_with_nu():
    # the press protocol: hand speed a fraction of the P-wave speed and CFL dt, so only the stress scale changes
    f = {}
    for E, nu in ((3.0, 0.25), (9.0, 0.25), (3.0, 0.4)):
        r = slab_press((0.5,), E=E, nu=nu, **TINY)
        f[(E, nu)] = float(np.interp(1.0, r.depth[0], r.force[0]))
    assert f[(9.0, 0.25)] / f[(3.0, 0.25)] == pytest.approx(3.0, rel=0.05)
    # a stiffer Poisson response: both the half-space (1 / (1 - nu^2)) and the thin layer (lambda + 2 mu) grow
    assert f[(3.0, 0.4)] > 1.05 * f[(3.0, 0.25)]


def test_momentum_change_equals_collider_impulse():
    m = free_slab_impact()
    assert m["impulse_rel"] > 0.5  # the sphere really stopped the slab
    assert m["rel_error"] < 1e-5


def test_free_oscillation_energy_does_not_grow():
    osc = free_oscillation(n_grid=32, width=4.0, thick=4.0, periods=1.0)
    tot = osc["total"]
    assert osc["kinetic"].min() < 0.5 * osc["kinetic"][0]  # it oscillates: kinetic energy turns elastic
    assert tot.max() <= tot[0] * 1.02  # no growth beyond the 1% wobble of this energy measure
    assert tot[-1] > 0.6 * tot[0]  # measured 0.77 on this 4-cell slab after one period
    p = osc["momentum"]
    assert np.abs(p - p[0]).max() < 1e-6 * np.sqrt(2 * tot[0])


def test_release_returns_to_rest_with_the_clamped_profile_only():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    res = {}
    for prof in ("clamped", "linear"):
        sim = EIPSimulator(
            SensorConfig(resolution=(16, 16), layers=4, alpha_profile=prof), PressConfig(n_grid=32, release_steps=200)
        )
        r = sim.press(mesh, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0])
        assert float(r.image[2].max()) > 0.2  # it was pressed
        res[prof] = float(r.residual.abs().max())
    assert res["clamped"] < 0.1  # cells
    assert res["linear"] > 3 * res["clamped"]


def test_normal_image_converges_with_resolution():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    imgs = {}
    for n in (32, 64):
        sensor = SensorConfig(resolution=(n // 2, n // 2), layers=n // 16 + 1)
        r = EIPSimulator(sensor, PressConfig(n_grid=n, depth=1.0 * n / 32)).press(
            mesh, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0]
        )
        imgs[n] = r.image / n  # domain units
    fine = torch.nn.functional.avg_pool2d(imgs[64][None], 2)[0]

    def corr(a, b):
        a, b = a.flatten() - a.mean(), b.flatten() - b.mean()
        return float((a * b).sum() / (a.norm() * b.norm()))

    # measured 0.945 (normal) on these 16- and 32-pixel pads
    assert corr(imgs[32][2], fine[2]) > 0.9
    assert corr(imgs[32][:2], fine[:2]) > 0.7


def test_contact_theory_curves_are_the_reference_formulas() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tvrecon.sim.validation.physics_checks import draw_contact_theory, hertz_force, winkler_radius

    fig, ax = plt.subplots(1, 2)
    d = np.linspace(0.1, 2.0, 5)
    draw_contact_theory(ax, 3.0, 0.25, 8.0, 4.0, 0.01, d)
    unit = 3.0 / (1 - 0.25**2) * 0.01**2
    np.testing.assert_allclose(ax[0].lines[0].get_ydata(), hertz_force(3.0, 0.25, 0.08, d * 0.01) / unit)
    np.testing.assert_allclose(ax[1].lines[1].get_ydata(), winkler_radius(8.0, d))
    assert [ln.get_label() for ln in ax[0].lines] == ["Hertz (half-space)", "thin layer h=4"]
    plt.close(fig)


def test_label_contact_axes_names_both_panels_and_their_limits():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tvrecon.sim.validation.physics_checks import draw_contact_theory, label_contact_axes

    fig, ax = plt.subplots(1, 2)
    draw_contact_theory(ax, 3.0, 0.25, 8.0, 4.0, 0.01, np.linspace(0.1, 2.0, 5))
    label_contact_axes(ax, "force, sphere", radius_xmin=-0.5, force_ymin=1e-1)
    assert ax[0].get_title() == "force, sphere" and ax[1].get_title() == "contact radius"
    assert ax[0].get_ylabel() == "F / (E* dx^2)" and ax[1].get_ylabel() == "contact radius a (cells)"
    assert ax[0].get_ylim()[0] == 1e-1 and ax[1].get_xlim()[0] == -0.5
    assert [t.get_text() for t in ax[1].get_legend().get_texts()] == ["Hertz sqrt(R d)", "thin layer sqrt(2 R d)"]
    plt.close(fig)
