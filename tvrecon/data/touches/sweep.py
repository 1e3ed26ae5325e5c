"""The paper's touches: a pad larger than the object, pressed through its centre along a sweep of directions.

The authors' simulator (yikaiw/EIP, ``config.py``, ``scene.py``, ``show_gear_*.py``) normalises the object to a max
extent of 0.16 of the domain, lays a pad of 0.24 x 0.04 x 0.24 domain units (1.5x the object, ~10 particle layers at
2 particles per cell) and drives the hand along the pad's centre line, which passes through the object's centre,
until the eq. 12 check stops it about 2.5 cells (~12% of the object's extent) past first contact. The paper's dataset
figure presses each object along a sweep of directions from the side to the top. :class:`PaperSweepTouchPolicy`
samples those touches; the pad and grid that give the authors' ratios are the data presets' ``sensor`` / ``press``
blocks (``configs/data/sensor/eip*.yaml``, ``configs/data/press/eip*.yaml``), checked by
:func:`eip_geometry_ratios`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch
import trimesh

from tvrecon.data.touches.policies import Touches, TouchPolicy
from tvrecon.utils.config_utils import OMIT_IF_DEFAULT
from tvrecon.utils.shape_check import check_shape

if TYPE_CHECKING:
    from tvrecon.sim.press.config import PressConfig
    from tvrecon.sim.press.simulator import EIPSimulator
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

__all__ = ["PaperSweepTouchPolicy", "eip_geometry_ratios", "outside_start", "sweep_directions"]

#: The authors' geometry at n_grid 128 (yikaiw/EIP): object max extent / domain, pad side / object, pad thickness /
#: object, press depth past first contact / object.
AUTHORS_RATIOS = {"object_fraction": 0.16, "pad_ratio": 1.5, "thickness_ratio": 0.25, "depth_fraction": 0.12}


def sweep_directions(azimuth: float, elevations_deg: np.ndarray) -> np.ndarray:
    """Press directions of a side-to-top sweep in one vertical plane (world +z up).

    Args:
        azimuth: the sweep's azimuth in radians (the horizontal direction the pad comes from).
        elevations_deg: (T,) elevation of the pad above the horizon in degrees: 0 presses from the side
            (horizontally), 90 from the top (straight down).

    Returns:
        (T, 3) float64 unit press directions, pointing from the pad into the object.
    """
    e = np.deg2rad(np.asarray(elevations_deg, dtype=np.float64))
    check_shape(e, "(T,)", "elevations_deg")
    out = np.stack([np.cos(e) * math.cos(azimuth), np.cos(e) * math.sin(azimuth), np.sin(e)], axis=1)
    return -out / np.linalg.norm(out, axis=1, keepdims=True)


@dataclass
class PaperSweepTouchPolicy(TouchPolicy):
    """The authors' touch protocol: centre aim, a side-to-top sweep of directions, a depth of ~12% of the object.

    Every touch's pad centre line passes through ``aim`` (the object's bounding-box centre), so a pad larger than
    the object (the presets' 1.5x) sees the object's whole outline from that side. An object's T touches sweep the
    elevation evenly from ``elevation_deg[0]`` (the side) to ``elevation_deg[1]`` (the top) in one vertical plane
    whose azimuth is drawn uniformly per object (with T = 10: 0, 10, ..., 90 degrees, 10 apart); ``azimuth_jitter_deg``
    turns each touch about the vertical by an extra uniform draw in +-jitter. A single touch (T = 1) draws its
    elevation uniformly in the range. Each press stops ``depth_fraction`` x the object's max extent past first
    contact (a ``depth`` stop in the press's cells; ``depth_fractions`` draws one per touch, uniformly).

    A part thinner than the object's distance table resolves (a spoon's bowl or a screwdriver's shaft under one of
    its cells thick) is not felt: the pad reads blank and the reading's ``contact`` is False. Pressing such a touch
    again deeper does not help (the pad passes through a part the table cannot hold), so the dataset keeps the blank
    reading (the cache entry's ``contact`` flag) and ``tvrecon.data.generate`` reports the misses per class. The cure
    is a finer table, not a finer grid: ``PressConfig.collider_refine`` (2 in ``press/eip_cpu``: the authors' 1/128
    on the CPU presets' 64 grid, where 9% of the touches felt nothing on the grid's own nodes and none do now).

    Attributes:
        elevation_deg: (first, last) elevation of the sweep in degrees above the horizon, in [-90, 90].
        depth_fractions: press depths past first contact as fractions of the object's max extent, each in (0, 0.5).
        azimuth_jitter_deg: per-touch extra turn about the vertical, uniform in +-this, degrees (0: one plane).
        aim: ``"centre"`` (the bounding-box centre, the authors') or ``"centroid"`` (the volume centroid).
        order: ``"sweep"`` (the touches in sweep order, side first) or ``"shuffled"`` (the same sweep in a random
            order). Reconstruction samples use the first T cached touches, so their presets shuffle: the first two
            touches are then any two of the sweep, not the two side ones. Classification draws its own touches.
        start: where on the centre line each touch's ``position`` is: ``"outside"`` (the plane that bounds the object
            on the pad's side, :func:`outside_start`) or ``"centre"`` (the aim point itself; the pad then finds the
            object from rays that start only ``clearance_cells`` in front of it, which lie inside an object that
            reaches farther along the press, e.g. a cube pressed at 45 degrees: that touch is rejected and re-drawn
            off the sweep. Kept to read caches made before ``"outside"``).
    """

    #: the module path of the class when its samples were first cached (tvrecon/data/touch_sweep.py): their keys hold
    key_target: ClassVar[str | None] = "tvrecon.data.touch_sweep.PaperSweepTouchPolicy"

    elevation_deg: Sequence[float] = (0.0, 90.0)
    depth_fractions: Sequence[float] = field(default_factory=lambda: (AUTHORS_RATIOS["depth_fraction"],))
    azimuth_jitter_deg: float = 0.0
    aim: str = "centre"
    order: str = field(default="sweep", metadata=OMIT_IF_DEFAULT)
    start: str = "outside"

    def __post_init__(self) -> None:
        what = type(self).__name__
        el = tuple(float(e) for e in self.elevation_deg)
        if len(el) != 2 or not all(-90.0 <= e <= 90.0 for e in el):
            raise ValueError(
                f"{what}.elevation_deg must be (first, last) in [-90, 90] degrees, got {self.elevation_deg}"
            )
        self.elevation_deg = el
        fr = tuple(float(f) for f in self.depth_fractions)
        if not fr or not all(0.0 < f < 0.5 for f in fr):
            raise ValueError(f"{what}.depth_fractions must be a non-empty list of fractions in (0, 0.5), got {fr}")
        self.depth_fractions = fr
        self.azimuth_jitter_deg = float(self.azimuth_jitter_deg)
        if not 0.0 <= self.azimuth_jitter_deg <= 180.0:
            raise ValueError(f"{what}.azimuth_jitter_deg must be in [0, 180], got {self.azimuth_jitter_deg}")
        if self.aim not in ("centre", "centroid"):
            raise ValueError(f"{what}.aim must be 'centre' or 'centroid', got {self.aim!r}")
        if self.order not in ("sweep", "shuffled"):
            raise ValueError(f"{what}.order must be 'sweep' or 'shuffled', got {self.order!r}")
        if self.start not in ("outside", "centre"):
            raise ValueError(f"{what}.start must be 'outside' or 'centre', got {self.start!r}")

    def sample(self, mesh, n, rng, camera=None, sim=None) -> Touches:  # the arguments of TouchPolicy.sample
        if sim is None:
            raise ValueError(
                f"{type(self).__name__} sizes its press depth in the simulator's cells: pass sim=EIPSimulator(...)"
            )
        azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
        lo, hi = self.elevation_deg
        elev = np.array([rng.uniform(min(lo, hi), max(lo, hi))]) if n == 1 else np.linspace(lo, hi, n)
        jitter = np.deg2rad(rng.uniform(-self.azimuth_jitter_deg, self.azimuth_jitter_deg, size=n))
        dirs = np.concatenate([sweep_directions(azimuth + j, e[None]) for j, e in zip(jitter, elev, strict=True)])
        centre = mesh.bounds.mean(axis=0) if self.aim == "centre" else mesh.center_mass
        extent_cells = self.extent_cells(mesh, sim)
        which = rng.integers(len(self.depth_fractions), size=n)
        if self.order == "shuffled":
            perm = rng.permutation(n)
            dirs, which = dirs[perm], which[perm]
        positions = outside_start(mesh, centre, dirs) if self.start == "outside" else np.repeat(centre[None], n, 0)
        return Touches(
            positions=torch.as_tensor(positions, dtype=torch.float32),
            directions=torch.as_tensor(dirs, dtype=torch.float32),
            normals=torch.as_tensor(-dirs, dtype=torch.float32),  # the face the pad meets: against the press
            strengths=[{"depth": round(self.depth_fractions[i] * extent_cells, 4)} for i in which],
        )

    @staticmethod
    def extent_cells(mesh: trimesh.Trimesh, sim: EIPSimulator) -> float:
        """The object's max extent in the press's grid cells."""
        return float(np.max(mesh.extents)) / float(sim.cfg.domain_size) * int(sim.cfg.n_grid)


def outside_start(mesh: trimesh.Trimesh, aim: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Each touch's start on its centre line: where the line leaves the slab the object fills along the press.

    ``aim - s d`` with ``s = max_v (v - aim) . (-d)`` over the mesh's vertices: the object lies wholly behind the plane
    through that point normal to ``d``, so the pad's footprint rays (cast from ``clearance_cells`` in front of the
    position, ``tvrecon.sim.press.placement.place_touch``) start outside it and meet its first surface, however far
    the object reaches along the press from ``aim`` (a cube's corner at 45 degrees: 0.71 of its side, 14.5 cells of
    the authors' 128 grid, past the 12 cells in front of the aim where the rays would start). The touch is the same:
    the pad's frame, touch point and press follow from the centre line and the first surface it meets.

    Args:
        mesh: the object, world coordinates. aim: (3,) the point every centre line passes through.
        directions: (T, 3) unit press directions (into the object).

    Returns:
        (T, 3) float64 positions.
    """
    d = np.asarray(directions, dtype=np.float64)
    check_shape(d, "(T, 3)", "directions")
    reach = ((np.asarray(mesh.vertices, dtype=np.float64) - aim) @ -d.T).max(axis=0)  # (T,) extent towards the pad
    return aim[None] - np.maximum(reach, 0.0)[:, None] * d


def eip_geometry_ratios(sensor: SensorConfig, press: PressConfig, object_extent: float = 1.0) -> dict[str, float]:
    """The ratios of a sensor / press pair to the object, to compare with :data:`AUTHORS_RATIOS`.

    Args:
        sensor, press: the pad and the press (the object has max extent ``object_extent`` world units).
        object_extent: the object's max extent in world units (the library normalises to 1.0).

    Returns:
        ``object_fraction`` (object / domain), ``pad_ratio`` (pad side / object), ``thickness_ratio`` (pad thickness /
        object), ``object_cells`` (object in cells) and ``pad_particles`` (P).
    """
    object_cells = float(object_extent) / float(press.domain_size) * int(press.n_grid)
    H, W = sensor.resolution
    side = max(H, W) * float(sensor.spacing)  # the pad's particles each fill a spacing-wide cube
    return {
        "object_fraction": float(object_extent) / float(press.domain_size),
        "pad_ratio": side / object_cells,
        "thickness_ratio": int(sensor.layers) * float(sensor.spacing) / object_cells,
        "object_cells": object_cells,
        "pad_particles": float(sensor.num_particles),
    }
