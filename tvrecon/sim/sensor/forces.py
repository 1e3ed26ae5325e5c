"""Per-taxel contact force field: the collider's force on the pad, per tactile pixel, in the sensor frame.

With the press's default particle contact (``PressConfig.contact="particle"``) each particle's force is its contact
impulse / dt (``MLSMPM.last_particle_force``; zero on particles off the object). With ``contact="grid"`` the solver
removes momentum from the grid nodes inside the object, and node i's force f_i is shared out over the particles that
gave it mass (``f_p = m_p sum_i w_ip f_i / m_i``, so nothing is lost).
A taxel (i, j) owns the pad's column of particles under it (every layer at (i, j)): the contact force reaches the
first layers through the B-spline stencil (1.5 cells), and the heavy back layer of a thin pad may take its share, so
summing the column keeps the field's total equal to the contact force (to float round-off) while each column's force
stays under the taxel it acts on. Channels (x shear, y shear, z normal) like the tactile image, z > 0 = the object
pushes into the pad. Simulation units (force = mass * domain units / s^2).

Every function takes leading batch dimensions and works on any device.
"""

from __future__ import annotations

import torch
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["column_force_field", "normal_shear", "field_total"]


def _check_field(field: Tensor, name: str = "field") -> None:
    if not isinstance(field, Tensor):
        raise ValueError(f"{name} must be a (..., H, W, 3) tensor, got {type(field).__name__}")
    check_shape(field, "(..., H, W, 3)", name)
    if not bool(torch.isfinite(field).all()):
        raise ValueError(f"{name} contains NaN or infinite values")


def column_force_field(particle_force: Tensor, resolution: tuple[int, int], layers: int) -> Tensor:
    """Sum the particle forces of each taxel's column through the pad.

    Args:
        particle_force: (..., P, 3) per-particle force in the sensor frame, pad order (layers, H, W) with
            P = layers * H * W (``tvrecon.sim.sensor.elastic_pad.pad_lattice``).
        resolution: (H, W) of the contact layer. layers: particles through the thickness.
    Returns:
        (..., H, W, 3) force per taxel, same dtype and device; sums to the particles' total.
    """
    H, W = (int(r) for r in resolution)
    L = int(layers)
    check_shape(particle_force, "(..., P, 3)", "particle_force")
    if particle_force.shape[-2] != L * H * W:
        raise ValueError(
            f"particle_force must have P = layers * H * W = {L * H * W} particles, got {tuple(particle_force.shape)}"
        )
    if not bool(torch.isfinite(particle_force).all()):
        raise ValueError("particle_force contains NaN or infinite values")
    lead = particle_force.shape[:-2]
    return particle_force.reshape(*lead, L, H, W, 3).sum(-4)


def normal_shear(field: Tensor) -> tuple[Tensor, Tensor]:
    """Split a force field into its normal and shear parts.

    Args:
        field: (..., H, W, 3) force per taxel, sensor frame.
    Returns:
        normal (..., H, W) (> 0 = pushing into the pad) and shear (..., H, W, 2) (x, y).
    """
    _check_field(field)
    return field[..., 2], field[..., :2]


def field_total(field: Tensor, frame: Tensor | None = None) -> Tensor:
    """Total force of a field, in the sensor frame or (with ``frame``) in world axes.

    Args:
        field: (..., H, W, 3) force per taxel, sensor frame.
        frame: optional (..., 3, 3) sensor frame R (world = R @ local), e.g. ``TactileReading.frame``.
    Returns:
        (..., 3) total force; equals ``TactileReading.force`` for a reading's field and frame.
    """
    _check_field(field)
    total = field.sum((-3, -2))
    if frame is None:
        return total
    check_shape(frame, "(..., 3, 3)", "frame")
    return (frame.to(total) @ total[..., None])[..., 0]
