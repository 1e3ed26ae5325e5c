"""How far from a body a particle can be and still be pushed by the particle contact this step (its search's reach).

The particle contact (:mod:`tvrecon.sim.mpm.particle_contact`) pushes a particle at signed distance ``phi >= 0`` only
when it approaches faster than ``phi / dt`` (``v . n < -phi / dt``, :func:`~.particle_contact.contact_velocity`), and
one inside (``phi < 0``) always. A particle's pass velocity is a convex combination of node velocities (paper eq. 8:
the weights ``w_ip`` sum to 1, and ``alpha_p`` mixes in the hand's velocity), so it is no faster than the fastest node
or the hand. Each Jacobi pass changes a node's velocity by a mass-weighted mean of the particles' changes ``alpha_p
dv_p`` (``sum_p w_ip alpha_p m_p dv_p / m_i`` with ``m_i = sum_p w_ip m_p``), and a change is at most ``(1 + mu) (c +
s)`` for speeds up to ``s`` (the normal part lifts ``v_n`` to at most the push-out cap ``c``; Coulomb friction removes
at most ``mu`` times it tangentially). So with ``s_1`` the fastest node or hand before the contact, the pass ``j``
sees speeds of at most ``s_{j+1} = s_j + (1 + mu) (c + s_j)``, and no particle farther than ``s_J dt`` (``J`` passes)
is pushed: a search to that distance finds every particle a search to a whole cell finds with a non-zero impulse, and
the step is the same, bit for bit (the dropped candidates scattered exact zeros).

On the old paper pad a pressing step moved the fastest node ~0.03 cells (a captured step): within this bound lay
2,949 particles a call on average against 4,687 within the cell the search took before (benchmarks/README.md).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["speed_reach"]

#: relative and absolute (in cells) slack on the bound: float32 round-off of the velocities and distances
_REL, _ABS_CELLS = 1e-3, 1e-3


def speed_reach(
    speed: Tensor,
    dt: float,
    dx: float,
    iterations: int,
    push_cap: float,
    friction: float = 0.0,
) -> Tensor:
    """0-dim: the distance within which the particle contact can push a particle this step, at most ``dx``.

    Args:
        speed: 0-dim, the largest velocity component of any node (before the contact) or of the hand (domain units /
            s; a component, so a speed is at most ``sqrt(3)`` times it). NaN or inf gives ``dx``.
        dt: the step. dx: the cell size, the search's reach without this bound.
        iterations: the contact's Jacobi passes. push_cap: the push-out's largest normal velocity (domain units / s).
        friction: the Coulomb coefficient.
    """
    s = math.sqrt(3.0) * speed.detach().float()  # the fastest node or hand, as a speed
    k = 1.0 + float(friction)
    for _ in range(iterations - 1):  # the speeds the later passes may see
        s = s + k * (push_cap + s)
    r = s * (dt * (1.0 + _REL)) + _ABS_CELLS * dx
    return torch.where(r < dx, r, torch.full_like(r, dx))  # NaN / inf: the whole cell
