"""Step-and-hold indentation (``slab_press(holds=...)``, :mod:`quasi_static`): the
Hertz exponents read at rest, and the physics of the hold (the damping does not move the equilibrium; during a
constant-speed press the pad's inertia adds force). Measured numbers in the comments: these scenes, one thread.
"""

from __future__ import annotations

import numpy as np
import pytest

from tvrecon.sim.validation.physics_checks import slab_press
from tvrecon.sim.validation.quasi_static import hand_schedule, hold_means, relaxation_steps

OFFSETS = (0.0, 0.25, 0.5, 0.75)
# the tiny scene of benchmarks/physics/bench_hertz_static.py: sphere R = 6 cells, pad 3 cells thick, n_grid 32
SCENE = {"n_grid": 32, "width": 12.0, "thick": 3.0, "R": 6.0}
HOLDS = (0.5, 1.0, 1.5)


def test_schedule_reaches_each_hold_exactly_and_holds_together():
    gaps = [2.5, 1.75, 2.25]
    inc, hold = hand_schedule(gaps, 0.3, 2.0, holds=(0.5, 1.0), hold_steps=4)
    travel = np.cumsum(inc, 1)
    for b, gap in enumerate(gaps):
        assert travel[b, -1] == pytest.approx(gap + 2.0)
        for k, depth in enumerate((0.5, 1.0)):
            assert np.allclose(travel[b, hold[b] == k] - gap, depth)  # at rest at the hold's depth
    for k in range(2):  # the last 4 steps of each hold are common to every scene (the damping acts on them)
        common = np.flatnonzero((hold == k).all(0))
        assert len(common) >= 4 and (inc[:, common] == 0).all()
    with pytest.raises(ValueError):
        hand_schedule(gaps, 0.3, 2.0, holds=(1.0, 0.5))
    assert relaxation_steps(12.0, 0.3, 1.0, 3.0) == 208  # 0.75 of 4 h / c_s, c_s dt = 0.3 / sqrt(3) cells


def test_hertz_exponents_at_rest_at_every_apex_offset():
    r = slab_press(OFFSETS, contact="particle", max_depth=HOLDS[-1], holds=HOLDS, **SCENE)
    assert r.hold is not None
    hd, hf, ha, har = hold_means(r.hold, r.depth, r.force, r.radius, r.area_radius)
    for b in range(len(OFFSETS)):
        assert np.allclose(hd[b], HOLDS)
        # measured: force 1.65-1.71, radius 0.49-0.51 (second moment), 0.48-0.50 (area)
        assert 1.5 < np.polyfit(np.log(hd[b]), np.log(hf[b]), 1)[0] < 2.0, OFFSETS[b]
        assert 0.4 < np.polyfit(np.log(hd[b]), np.log(ha[b]), 1)[0] < 0.6, OFFSETS[b]
        assert 0.4 < np.polyfit(np.log(hd[b]), np.log(har[b]), 1)[0] < 0.6, OFFSETS[b]
        # the pad's inertia: arriving at the first hold at 0.1 c_p the force is 1.43-1.60x the force at rest there
        arrive = int(np.flatnonzero(r.hold[b] == 0)[0]) - 1
        assert r.force[b, arrive] > 1.2 * hf[b, 0], OFFSETS[b]
    # the offsets agree at rest (measured 1.5% at d = 1 cell)
    assert hf[:, 1].max() / hf[:, 1].min() < 1.05


def test_relaxation_damping_does_not_move_the_equilibrium():
    scene = {**SCENE, "max_depth": 1.0, "holds": (1.0,)}
    damped = slab_press((0.5,), contact="particle", **scene)  # the default hold: 52 damped steps
    free = slab_press((0.5,), contact="particle", hold_steps=552, hold_damping=0.0, **scene)  # 8 shear periods
    assert damped.hold is not None and free.hold is not None
    f_damped = hold_means(damped.hold, damped.depth, damped.force)[1][0, 0]
    tail = free.force[0, np.flatnonzero(free.hold[0] == 0)][276:]  # the undamped pad still rings: 3% std
    # measured: 0.02172 damped, 0.02229 undamped (mean of the last 4 periods), 2.6% apart
    assert abs(tail.mean() / f_damped - 1) < 0.05
    settled = damped.force[0, np.flatnonzero(damped.hold[0] == 0)][-26:]
    assert settled.std() / settled.mean() < 0.01  # measured 0.002
