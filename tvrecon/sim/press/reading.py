"""What a press returns: :class:`TactileReading`, one simulated touch, and its contact patch in world coordinates
(:func:`reading_patch`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from torch import Tensor

from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig
from tvrecon.sim.sensor.patch import ContactPatch, contact_patch

__all__ = ["TactileReading", "reading_patch"]


@dataclass
class TactileReading:
    """One simulated touch.

    Attributes:
        image: (3, H, W) float32 contact-layer displacement in the sensor frame with the hand translation removed,
            in grid cells; channels (x shear, y shear, z normal), z > 0 = pushed into the pad.
        position: (3,) float32 world coordinates of the centre of the tactile pixels (rest contact layer moved
            with the hand) at the reading.
        direction: (3,) float32 unit press direction in world coordinates.
        steps: press steps simulated.
        depth: indentation past first contact (hand travel minus gap), in cells, >= 0.
        chamfer: :func:`terminal_chamfer` of the contact layer at the reading (squared cells per particle).
        force: (3,) float32 contact force on the pad in world axes (simulation units), at the last press step.
        force_field: (H, W, 3) float32 the same force per taxel in the sensor frame (x shear, y shear, z normal;
            z > 0 = pushing into the pad), summing to ``force`` (``R^T force``) to float round-off; see
            :mod:`tvrecon.sim.sensor.forces`.
        contact: whether the object ever pushed on the pad.
        frame: (3, 3) float32 sensor frame R (columns e_x, e_y, e_z in world), world = R @ local.
        origin: (3,) float32 world point at the touch point (domain (0.5, 0.5, 0.5 + dx / 2)).
        residual: (3, H, W) image after the release phase, or None without release.
        frames: (K, 3, H, W) recorded images (``record_every``), or None.
        frame_steps: the K step indices of ``frames``.
        particles: (K, P, 3) recorded pad particle positions in world coordinates, or None.
        criterion_missed: the press stopped at its travel limit (``max_depth`` / ``max_steps``) before its stop
            criterion (``depth``, ``force`` or ``threshold``) was reached; a ``RuntimeWarning`` says so too.
    """

    image: Tensor
    position: Tensor
    direction: Tensor
    steps: int
    depth: float
    chamfer: float
    force: Tensor
    contact: bool
    frame: Tensor | None = None
    origin: Tensor | None = None
    residual: Tensor | None = None
    frames: Tensor | None = None
    frame_steps: list[int] = field(default_factory=list)
    particles: Tensor | None = None
    force_field: Tensor | None = None
    criterion_missed: bool = False

    def cpu(self) -> TactileReading:
        """This reading with every tensor on the CPU (a reading pressed on a GPU, for pictures and numpy)."""
        moved = {
            f.name: value.cpu() for f in dataclasses.fields(self) if isinstance(value := getattr(self, f.name), Tensor)
        }
        return dataclasses.replace(self, **moved)


def reading_patch(reading: TactileReading, sensor: SensorConfig, press: PressConfig) -> ContactPatch:
    """:func:`contact_patch` of one reading of a simulator with these configs (points (H*W, 3), mask (H*W,)).

    Usage: ``reading_patch(sim.press(mesh, position, direction), sim.sensor, sim.cfg)``.
    """
    return contact_patch(reading.image, reading.position, reading.direction, sensor, press.n_grid, press.domain_size)
