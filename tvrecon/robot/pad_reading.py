"""What a robot pad reads: one pad's reading (:class:`FingerReading`), the engine's contact points it is made from
(:class:`ContactPoint`) and the per-frame log of the readings (:func:`reading_record`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

__all__ = ["ContactPoint", "FingerReading", "reading_record"]


@dataclass
class FingerReading:
    """One tactile reading of a pad.

    image: (3,H,W) float32 pad-frame displacement in grid cells (x shear, y shear, z normal; z > 0 into the pad).
    contact: True if the link touches a registered object with at least ``min_force``.
    force: total engine normal force (N); force_vec: (3,) float64 world force the object exerts on the finger.
    position: (3,) float64 world contact point (force-weighted, on the object); nan without contact.
    direction: (3,) float64 unit world press direction (the pad normal, into the object).
    penetration: max engine penetration (m, >= 0); depth: indentation used for the press (m).
    body: the touched object's key (pybullet body id, MuJoCo geom id; -1 = none); simulated: True if this call ran
    a new EIP press.
    force_field: (3,H,W) float32 pad-frame force per taxel (x, y shear, z normal; simulation units of
    ``tvrecon.sim.sensor.forces``); zeros at rest.
    patch: (M,3) float64 world points of the contact layer's taxels in contact (the contact patch, moved with the
    link since the press); (0,3) at rest.
    spacing: grid cells between neighbouring taxels (for :meth:`rgb` and :meth:`markers`).
    """

    image: np.ndarray
    contact: bool
    force: float
    force_vec: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    penetration: float
    depth: float
    body: int
    simulated: bool
    extra: dict = field(default_factory=dict)
    force_field: np.ndarray | None = None
    patch: np.ndarray | None = None
    spacing: float = 0.5

    def rgb(self, **kwargs: object) -> np.ndarray:
        """(3,H,W) float32 GelSight-style RGB in [0, 1] (``tvrecon.sim.sensor.photometric.render_rgb``; kwargs pass
        on)."""
        from tvrecon.sim.sensor.photometric import render_rgb

        img = torch.as_tensor(np.asarray(self.image, dtype=np.float32))
        return render_rgb(img, taxel_spacing=self.spacing, **kwargs).numpy()

    def markers(self, marker_spacing: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
        """Marker grid seen from behind the pad (``tvrecon.sim.sensor.markers``).

        Returns:
            ((M,2) float32 rest positions, (M,2) float32 displaced positions), (x, y) taxel coordinates.
        """
        from tvrecon.sim.sensor.markers import marker_grid, marker_positions

        img = torch.as_tensor(np.asarray(self.image, dtype=np.float32))
        rest = marker_grid(tuple(img.shape[-2:]), spacing=marker_spacing)
        return rest.numpy(), marker_positions(img, rest, taxel_spacing=self.spacing).numpy()


@dataclass
class ContactPoint:
    """One engine contact between a pad link and an object, in world coordinates (metres, newtons).

    key: the object's key in :attr:`PadSensor.objects`; position: (3,) point on the object's surface;
    normal: (3,) unit normal from the object towards the pad; penetration: overlap (m, >= 0); force: normal force (N).
    """

    key: int
    position: np.ndarray
    normal: np.ndarray
    penetration: float
    force: float


def reading_record(readings: Sequence[FingerReading]) -> dict[str, np.ndarray]:
    """The per-frame log entries of the pads' readings, one row per pad (what both pick-and-place demos store).

    Returns contact (F,) bool, force (F,), force_vec (F, 3), contact_pos (F, 3), direction (F, 3), penetration (F,),
    depth (F,), simulated (F,) bool and tactile (F, 3, H, W) float32.
    """
    return {
        "contact": np.array([r.contact for r in readings]),
        "force": np.array([r.force for r in readings]),
        "force_vec": np.stack([r.force_vec for r in readings]),
        "contact_pos": np.stack([r.position for r in readings]),
        "direction": np.stack([r.direction for r in readings]),
        "penetration": np.array([r.penetration for r in readings]),
        "depth": np.array([r.depth for r in readings]),
        "simulated": np.array([r.simulated for r in readings]),
        "tactile": np.stack([r.image for r in readings]).astype(np.float32),
    }
