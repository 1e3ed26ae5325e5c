"""Step-and-hold indentation: the hand of :func:`physics_checks.slab_press` stops at a list
of depths and holds, so that force and contact radius are read at rest, as an indentation test reads them.

Why: Hertz and the thin-layer limit are static solutions. A pad pressed at a speed v carries momentum. When its
contact layer is stopped by a rigid body, a compression wave of stress ``rho c_p v = M v / c_p`` (the 1-D impact
stress, ``M = lambda + 2 mu`` the P-wave modulus) leaves the contact area. Until it has crossed the layer and come back
from the rigid back (``2 h / c_p``, i.e. ``2 h v / c_p`` cells of travel: 2.4 cells at ``v = 0.1 c_p`` and ``h = 12``)
the force holds an inertial part of the order of ``M (v / c_p) A`` over the contact area A; later the layer rings about
the static force. Measured on the issue's scene (R = 32, h = 12 cells, n_grid 256, particle contact): at d = 0.75
cells the force during the press is 2.2x the force at rest (the excess is 0.6 of ``M (v / c_p) pi a^2``), at d = 2.67
cells 6-8% above. A log-log fit from d = 0.75 cells starts inside that first transit and comes out flat (force
exponent 1.37 instead of 1.75 at rest). Holding the hand still lets the wave ring down, and the mean over the end of
the hold is the static value. The transfers alone dissipate it slowly (:func:`physics_checks.free_oscillation`:
about 13% of the energy per period), so during a hold the grid velocities are damped, ``v_i *= exp(-c dt)``
(``MPMConfig.damping``): dynamic relaxation (Otter, Cassell & Hobbs, "Dynamic relaxation", Proc. ICE 35, 1966;
Underwood, "Dynamic relaxation", in Belytschko & Hughes, Computational Methods for Transient Analysis, 1983), the
standard way to reach a static solution with an explicit dynamic code. The damping force ``-c m v`` vanishes at
rest, so it does not change the equilibrium, only how fast it is reached; the hand moves undamped.
:func:`relaxation_damping` takes ``c`` twice the angular frequency of the layer's lowest thickness-shear mode,
``2 pi c_s / 4h`` (critical for that mode); every mode at or above that frequency then decays as ``exp(-c t / 2)``.

The schedule is per scene: scenes whose apex sits at another offset have another start gap, and each holds at the
same depths of its own; the first to arrive waits, so the damped part of every hold is common to all scenes. The last
step before a hold is shortened so that the hold starts exactly at its depth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["hand_schedule", "hold_means", "relaxation_damping", "relaxation_steps"]

#: Hold length in periods of the layer's lowest thickness-shear mode (:func:`relaxation_steps`). Measured on the
#: issue's Hertz scene (R = 32, h = 12 cells, n_grid 256, particle contact): after 0.72 periods (200 steps) the force
#: over the last half of a hold varies by under 1.5% (std), against 7-22% without the damping.
HOLD_PERIODS = 0.75


def relaxation_damping(mu: float, rho: float, thick: float) -> float:
    """Grid-velocity damping rate (1/s) of dynamic relaxation for a layer of thickness ``thick`` (domain units) bonded
    to a rigid back: ``c = 2 omega_1 = pi c_s / thick`` with ``omega_1 = 2 pi c_s / (4 thick)`` the lowest
    thickness-shear mode of a clamped-free layer and ``c_s = sqrt(mu / rho)``."""
    return math.pi * math.sqrt(mu / rho) / thick


def relaxation_steps(thick_cells: float, cfl: float, mu: float, M: float, periods: float = HOLD_PERIODS) -> int:
    """Steps of a hold: ``periods`` of the lowest thickness-shear mode of a clamped-free layer, ``4 h / c_s``, at the
    CFL step ``c_p dt = cfl`` cells (so ``c_s dt = cfl sqrt(mu / M)`` cells, ``M = lambda + 2 mu``)."""
    return int(math.ceil(periods * 4.0 * thick_cells / (cfl * math.sqrt(mu / M))))


def hand_schedule(
    gaps: Sequence[float], step_cells: float, max_depth: float, holds: Sequence[float] = (), hold_steps: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-scene hand travel per step: move ``step_cells`` per step, stop at each depth of ``holds`` (depth = travel
    minus the scene's gap) and end at ``max_depth``. The holds are synchronised: a scene that arrives first waits for
    the others, then all hold ``hold_steps`` steps together (so a solver-wide damping can act on the common part);
    scenes that end early hold.

    Args:
        gaps: (B,) start gaps in cells. step_cells: travel per moving step, cells. max_depth: final depth, cells.
        holds: increasing depths (cells, up to ``max_depth``) to hold at. hold_steps: steps per hold.
    Returns:
        (B, S) float64 travel per step (cells) and (B, S) int64 hold index per step (-1 while moving or after the
        last hold; k while waiting at or holding hold k).
    """
    if any(not 0 < h <= max_depth for h in holds) or list(holds) != sorted(set(holds)):
        raise ValueError(f"holds must increase within (0, max_depth={max_depth}], got {list(holds)}")
    B = len(gaps)
    inc: list[list[float]] = [[] for _ in range(B)]
    idx: list[list[int]] = [[] for _ in range(B)]
    travel = [0.0] * B
    for k, target in enumerate([*holds, max_depth]):
        for b, gap in enumerate(gaps):
            while travel[b] < gap + target - 1e-9:
                step = min(step_cells, gap + target - travel[b])
                inc[b].append(step)
                idx[b].append(-1)
                travel[b] += step
        if k == len(holds):
            break
        arrive = max(len(r) for r in inc)
        for b in range(B):
            wait = arrive - len(inc[b]) + hold_steps
            inc[b].extend([0.0] * wait)
            idx[b].extend([k] * wait)
    S = max(len(r) for r in inc)
    out = np.zeros((B, S))
    hold = np.full((B, S), -1, dtype=np.int64)
    for b in range(B):
        out[b, : len(inc[b])] = inc[b]
        hold[b, : len(idx[b])] = idx[b]
    return out, hold


def hold_means(hold: np.ndarray, depth: np.ndarray, *values: np.ndarray, tail: float = 0.5) -> list[np.ndarray]:
    """The static value at each hold: the mean over the last ``tail`` of its steps (keep ``tail`` below the common
    part, ``hold_steps``, of the schedule).

    Args:
        hold: (B, S) hold index per step (:func:`hand_schedule`). depth: (B, S) depth per step, cells.
        values: (B, S) per-step records (force, radius, ...). tail: fraction of each hold averaged.
    Returns:
        [(B, K) depth, then (B, K) of each value], K = the number of holds.
    """
    K = int(hold.max()) + 1
    out = [np.zeros((hold.shape[0], K)) for _ in range(len(values) + 1)]
    for b in range(hold.shape[0]):
        for k in range(K):
            steps = np.flatnonzero(hold[b] == k)
            steps = steps[len(steps) - max(1, int(round(tail * len(steps)))) :]
            for arr, src in zip(out, (depth, *values)):
                arr[b, k] = float(src[b, steps].mean())
    return out
