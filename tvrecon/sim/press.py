"""The EIP press protocol (paper Algorithm 1): place a sensor pad against a mesh and press until a stop rule.

Coordinates. For every touch the simulation domain ``[0, 1)^3`` (``n_grid`` cells spanning ``domain_size`` world
units) is attached to the *sensor frame* (see :func:`tvrecon.sim.sensor.sensor_frame`): domain x, y follow the
contact plane and domain -z is the press direction, so the pad is aligned with the grid whatever the world
direction. The domain point (0.5, 0.5, 0.5 + dx / 2) is the *touch point*: laterally the given ``position``, along the
press axis the highest point of the object under the pad's footprint (found by ray casting), so the pad starts
``gap`` cells in front of the first point it will touch. World <-> domain::

    u = R^T (w - origin) / domain_size + c        w = origin + R (u - c) domain_size,   c = (0.5, 0.5, 0.5 + dx / 2)

(the touch plane lies half-way between grid node planes, see :func:`tvrecon.sim.placement.touch_z`)

The concepts live in their own modules; this one holds the configuration and the public entry points:

- :mod:`tvrecon.sim.placement`: ray casts from the pad's footprint, reach, the default touch point, the data
  pipeline's reachability test (``pad_footprint``, ``pad_reachable``);
- :mod:`tvrecon.sim.stop_rules`: the ordered stop rules (travel limit, then the first configured of ``depth`` >
  ``force`` > ``threshold``, the terminal check of Algorithm 1, :func:`terminal_chamfer`); a ``depth`` raises
  ``max_depth`` to ``depth + 0.5`` when shorter (:func:`~tvrecon.sim.stop_rules.travel_for_depth`);
- :mod:`tvrecon.sim.press_run`: the solver loop, each touch going approach -> press -> release -> done, and the
  :class:`TactileReading` it returns.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.config_utils import (
    OMIT_IF_DEFAULT,
    check_instance,
    check_known_keys,
    check_number,
    check_whole,
    field_names,
)
from tvrecon.sim import placement
from tvrecon.sim.materials import p_wave_speed
from tvrecon.sim.mpm import MPMConfig, cfl_dt
from tvrecon.sim.particle_contact import CONTACT_MODES
from tvrecon.sim.press_run import PressLoop, TactileReading
from tvrecon.sim.sensor import SensorConfig, _scalar
from tvrecon.sim.stop_rules import (
    DEFAULT_THRESHOLD,
    TERMINAL_MEASURES,
    chamfer_eq13,
    chamfer_reaches,
    terminal_chamfer,
    travel_for_depth,
)

__all__ = [
    "DEFAULT_THRESHOLD",
    "EIPSimulator",
    "PressConfig",
    "SensorConfig",
    "TactileReading",
    "chamfer_eq13",
    "chamfer_reaches",
    "terminal_chamfer",
]


@dataclass
class PressConfig:
    """How a touch is simulated.

    Attributes:
        n_grid: grid cells across the domain (dx = 1 / n_grid in domain units).
        domain_size: world units spanned by the domain (the mesh is scaled by 1 / domain_size).
        gap: start gap between the contact layer and the object's highest point under the pad, in cells. With the
            default particle contact the pad touches when its particles reach the surface, so the hand first travels
            the gap (the first step touches only when ``gap`` is below one step's travel). The grid contact
            (``contact="grid"``) reaches the node plane 1.5 cells below the particles; with the touch plane half-way
            between node planes (``placement.touch_z``) the default 1.0 is the smallest gap that starts out of grid
            contact, and its first step already touches (no approach steps). Below 1.0 the pad starts in grid contact.
        speed: hand speed v_r in domain units / s; None -> ``speed_fraction`` * elastic (P-)wave speed.
        speed_fraction: fraction of the P-wave speed sqrt((lambda + 2 mu) / rho) used when ``speed`` is None.
        threshold: :func:`terminal_chamfer` threshold (squared cells per contact particle); the default stop rule.
        depth: stop at this indentation past first contact (cells); overrides ``force`` and ``threshold``. Raises
            ``max_depth`` to ``depth + 0.5`` for the call when shorter (``stop_rules.travel_for_depth``).
        force: stop when the normal contact force reaches this (simulation units); overrides ``threshold``.
        max_depth: the hand never travels more than ``gap + max_depth`` cells (also bounds the collider region and
            the reach); a longer ``depth`` raises it (see ``depth``).
        max_steps: hard step limit of the press phase; None -> the steps needed for ``gap + max_depth``.
        friction: Coulomb friction coefficient of the collider (on nodes or particles, per ``contact``).
        dt: time step; None -> CFL rule of the solver (``cfl_dt``).
        release_steps: after pressing, retract the hand at ``speed`` (back to its start) and hold, for this
            many steps in total; the reading then carries the ``residual`` image.
        record_every: record the tactile image and the pad particles every this many steps (0 = off).
        progress: show a tqdm progress bar over the steps.
        contact: where the rigid object acts on the pad (``MPMConfig.contact``, whose own default stays ``"grid"``):
            ``"particle"`` (default: the contact-layer particles, from when they reach the surface, whatever the
            object's offset from the node planes; :mod:`tvrecon.sim.particle_contact`; meets the Hertz exponent
            targets, docs/physics.md) or ``"grid"`` (the grid nodes with sdf < 0; contact starts up to 1.5 cells
            before the particles arrive; the default before issue 15 item 1).
        threshold_grid: the grid whose cells measure ``threshold``. An int N (default 128): squared cells of an
            N-cell grid, a fixed physical length (``domain_size / N`` world units); the terminal check compares the
            chamfer with ``threshold * (n_grid / N)^2``, so the default stops every grid where paper eq. 12 stops at
            the paper's ``n_grid`` 128 (at ``n_grid`` 64 the threshold is 1/4 of ``threshold`` in own cells, at 256
            4x). None: this press's ``n_grid`` (paper eq. 12 in the simulation's own cells, so the physical depth at
            the stop shrinks as ``n_grid`` grows; the default before issue 15 item 1).
        terminal: what ``threshold`` is compared with: ``"chamfer"`` (default: paper eq. 12, :func:`terminal_chamfer`)
            or ``"displacement"`` (beyond the paper: the same centred deformation with each particle matched to its
            own rest position, :func:`~tvrecon.sim.stop_rules.terminal_displacement`, ``DisplacementRule``). Eq. 12's
            nearest neighbours stop seeing a sideways spread once it passes half the lattice spacing (a quarter
            cell), so on a face larger than the pad the chamfer stop comes deeper on finer grids (0.61 of the 256
            depth at 128); the displacement stop does not (0.98-0.99). Elsewhere the two agree. docs/physics.md, "The
            stop depth across the object library".

    The press before issue 15 item 1 (grid-node collider, threshold in the press's own cells) is
    ``PressConfig(contact="grid", threshold_grid=None)`` (CLI: ``--contact grid --threshold-grid 0``).
    ``contact``, ``threshold_grid`` and ``terminal`` were added after data was cached; at their defaults they stay out
    of the data cache key (``config_utils.OMIT_IF_DEFAULT``) and other values (``"grid"``, None, ``"displacement"``)
    enter it. Flipping the ``contact`` and ``threshold_grid`` defaults changed every default touch, so the data cache
    version was bumped with it (``tvrecon.data.cache.CACHE_VERSION``).
    """

    n_grid: int = 128
    domain_size: float = 1.0
    gap: float = 1.0
    speed: float | None = None
    speed_fraction: float = 0.1
    threshold: float | None = DEFAULT_THRESHOLD
    depth: float | None = None
    force: float | None = None
    max_depth: float = 4.0
    max_steps: int | None = None
    friction: float = 0.0
    dt: float | None = None
    release_steps: int = 0
    record_every: int = 0
    progress: bool = False
    contact: str = field(default="particle", metadata=OMIT_IF_DEFAULT)
    threshold_grid: int | None = field(default=128, metadata=OMIT_IF_DEFAULT)
    terminal: str = field(default="chamfer", metadata=OMIT_IF_DEFAULT)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ValueError (TypeError for a value of the wrong type) naming the bad field."""
        check_whole(self.n_grid, "PressConfig.n_grid")
        for name in ("max_steps", "release_steps", "record_every"):
            if getattr(self, name) is not None:
                check_whole(getattr(self, name), f"PressConfig.{name}")
        for name in ("domain_size", "gap", "speed_fraction", "max_depth", "friction"):
            check_number(getattr(self, name), f"PressConfig.{name}")
        for name in ("speed", "threshold", "depth", "force", "dt"):
            if getattr(self, name) is not None:
                check_number(getattr(self, name), f"PressConfig.{name}")
        if int(self.n_grid) < 16:
            raise ValueError(f"PressConfig.n_grid must be >= 16, got {self.n_grid}")
        if not (math.isfinite(float(self.domain_size)) and float(self.domain_size) > 0):
            raise ValueError(f"PressConfig.domain_size must be > 0 world units, got {self.domain_size}")
        if not float(self.gap) >= 0:
            raise ValueError(f"PressConfig.gap must be >= 0 cells, got {self.gap}")
        for name in ("speed", "threshold", "depth", "force", "dt"):
            val = getattr(self, name)
            if val is not None and not _scalar(val) > 0:
                raise ValueError(f"PressConfig.{name} must be > 0 or None, got {val}")
        if not (0 < float(self.speed_fraction) < 1):
            raise ValueError(f"PressConfig.speed_fraction must be in (0, 1), got {self.speed_fraction}")
        if not float(self.max_depth) > 0:
            raise ValueError(f"PressConfig.max_depth must be > 0 cells, got {self.max_depth}")
        if self.max_steps is not None and int(self.max_steps) < 1:
            raise ValueError(f"PressConfig.max_steps must be >= 1 or None, got {self.max_steps}")
        if int(self.release_steps) < 0 or int(self.record_every) < 0:
            raise ValueError("PressConfig.release_steps and record_every must be >= 0")
        if not float(self.friction) >= 0:
            raise ValueError(f"PressConfig.friction must be >= 0, got {self.friction}")
        if self.contact not in CONTACT_MODES:
            raise ValueError(f"PressConfig.contact must be one of {CONTACT_MODES}, got {self.contact!r}")
        tg = self.threshold_grid
        if tg is not None and not (isinstance(tg, int) and not isinstance(tg, bool) and tg > 0):
            raise ValueError(f"PressConfig.threshold_grid must be a positive int or None, got {self.threshold_grid!r}")
        if self.terminal not in TERMINAL_MEASURES:
            raise ValueError(f"PressConfig.terminal must be one of {TERMINAL_MEASURES}, got {self.terminal!r}")


class EIPSimulator:
    """Press a sensor pad onto meshes with MLS-MPM and read the tactile images.

    Args:
        sensor: pad geometry and material (default :class:`SensorConfig`).
        press: press protocol (default :class:`PressConfig`).
        device: torch device of the simulation.
        compile: run the solver's no-grad steps with the fused ``torch.compile`` kernels (``MLSMPM(compile=...)``;
            None -> the ``TVRECON_COMPILE`` environment variable). A speed option, deliberately not a config field:
            readings equal the eager ones to float32 round-off, so it stays out of the data cache key.
    """

    def __init__(
        self,
        sensor: SensorConfig | None = None,
        press: PressConfig | None = None,
        device: torch.device | str = "cpu",
        compile: bool | None = None,
    ) -> None:
        self.sensor = sensor if sensor is not None else SensorConfig()
        self.cfg = press if press is not None else PressConfig()
        check_instance(self.sensor, SensorConfig, "EIPSimulator sensor")
        check_instance(self.cfg, PressConfig, "EIPSimulator press")
        self.device = torch.device(device)
        self.compile = compile

    # ------------------------------------------------------------------ configuration
    def _configs(self, overrides: dict) -> tuple[SensorConfig, PressConfig]:
        """The sensor and press configs of one call: the simulator's with ``overrides``; a ``depth`` stop rule
        raises ``max_depth`` to ``depth + 0.5`` cells when shorter (:func:`travel_for_depth`)."""
        s_names, p_names = set(field_names(SensorConfig)), set(field_names(PressConfig))
        check_known_keys(overrides, s_names | p_names, "press")
        s = dataclasses.replace(self.sensor, **{k: v for k, v in overrides.items() if k in s_names})
        p = dataclasses.replace(self.cfg, **{k: v for k, v in overrides.items() if k in p_names})
        return s, travel_for_depth(p)

    @staticmethod
    def wave_speed(sensor: SensorConfig) -> float:
        """Elastic P-wave speed sqrt((lambda + 2 mu) / rho) in domain units / s."""
        return p_wave_speed(_scalar(sensor.E), _scalar(sensor.nu), float(sensor.rho))

    def _mpm_config(self, s: SensorConfig, p: PressConfig) -> MPMConfig:
        cfg = MPMConfig(
            n_grid=int(p.n_grid),
            dt=p.dt,
            E=s.E,
            nu=s.nu,
            rho=float(s.rho),
            friction=float(p.friction),
            damping=s.damping,
            contact=p.contact,
        )
        if cfg.dt is None:
            probe = MPMConfig(n_grid=int(p.n_grid), E=_scalar(s.E), nu=_scalar(s.nu), rho=float(s.rho))
            cfg.dt = float(cfl_dt(probe))
        return cfg

    # ------------------------------------------------------------------ scene set-up
    def _setup(self, mesh: trimesh.Trimesh, position, direction, s: SensorConfig, p: PressConfig):
        """One touch's :class:`~tvrecon.sim.placement.Placement` (frame, touch point, collider)."""
        return placement.place_touch(mesh, position, direction, s, p, self.device)

    # ------------------------------------------------------------------ public API
    def touch_position(self, mesh: trimesh.Trimesh, direction, **overrides) -> Tensor:
        """A touch point the pad reaches from outside along ``direction``: the placement when none is given.

        The pad's footprint (its contact-layer particles, in the press frame) is centred on the line along
        ``direction`` through the centre of the mesh's bounding box. A ray along ``direction`` from outside the
        bounding box through each footprint particle meets the object's first surface; the touch
        point is on the centre line at the highest of these hits (the first point the pad will touch), so the pad
        starts clear of the object however much the surface rises under it. When every ray misses (e.g. the hole
        of a torus), the footprint moves so that its most central particle is over the hit nearest the centre line
        among rays cast over the whole bounding box (:func:`tvrecon.sim.placement.touch_position`). (The data
        pipeline samples its own touches, see ``tvrecon.data.touches``.)

        Args:
            mesh: object in world coordinates. direction: (3,) world press direction (into the object).
            **overrides: :class:`SensorConfig` / :class:`PressConfig` fields, as for :meth:`press` (the footprint
                follows the pad's resolution, spacing, ``n_grid`` and ``domain_size``).
        Returns:
            (3,) float32 world point to pass as ``position``.
        Raises:
            ValueError: no ray along ``direction`` meets the mesh (e.g. a flat plane pressed along itself).
        """
        s, p = self._configs(overrides)
        return placement.touch_position(mesh, direction, s, p)

    def press(self, mesh: trimesh.Trimesh, position, direction, **overrides) -> TactileReading:
        """Press the pad onto ``mesh`` at ``position`` along ``direction``.

        Args:
            mesh: object in world coordinates. Watertight, or open (an open box, a plane, a mesh with holes):
                an open mesh is solid behind the first surface the pad meets (``MeshCollider(from_above=True)``).
                A touch that travels past the surface found under the pad without feeling it (a part thinner
                than the grid resolves) warns (RuntimeWarning) instead of returning a silent miss.
            position: (3,) world point on or near the surface; None -> :meth:`touch_position` finds one.
            direction: (3,) world press direction, pointing into the object (any non-zero length).
            **overrides: any :class:`SensorConfig` or :class:`PressConfig` field for this call (E and nu may be
                0-dim tensors requiring grad, ``speed`` too: the image is differentiable w.r.t. them).
        Returns:
            the :class:`TactileReading`.
        """
        if position is None:
            position = self.touch_position(mesh, direction, **overrides)
            reading = self.press_batch([mesh], [position], [direction], **overrides)[0]
            if reading.steps == 0:  # the pad's rays met nothing at the touch point found for it
                raise ValueError(
                    f"the pad finds no surface under its footprint along the direction "
                    f"{np.asarray(direction, dtype=float).tolist()}: the object is thinner than the pad's particle "
                    "spacing seen along it (e.g. a sheet pressed on its edge). Choose another direction, give a "
                    "position, or raise n_grid"
                )
            return reading
        return self.press_batch([mesh], [position], [direction], **overrides)[0]

    def press_batch(
        self, meshes: Sequence[trimesh.Trimesh] | trimesh.Trimesh, positions, directions, **overrides
    ) -> list[TactileReading]:
        """Simulate T touches in one solver loop (one independent grid block per touch).

        Each touch stops at its own terminal condition and then leaves the loop; results equal T calls of
        :meth:`press` up to float round-off.

        Args:
            meshes: T meshes (or one mesh used for every touch), world coordinates.
            positions: (T, 3) world points. directions: (T, 3) world press directions.
        Returns:
            T :class:`TactileReading`.
        """
        s, p = self._configs(overrides)
        pos = (
            torch.as_tensor(np.asarray(positions, dtype=np.float32)) if not isinstance(positions, Tensor) else positions
        )
        dirs = (
            torch.as_tensor(np.asarray(directions, dtype=np.float32))
            if not isinstance(directions, Tensor)
            else directions
        )
        if pos.ndim != 2 or pos.shape[-1] != 3:
            raise ValueError(f"positions must have shape (T, 3), got {tuple(pos.shape)}")
        if dirs.shape != pos.shape:
            raise ValueError(
                f"directions must have shape (T, 3) like positions {tuple(pos.shape)}, got {tuple(dirs.shape)}"
            )
        T = pos.shape[0]
        if isinstance(meshes, trimesh.Trimesh):
            meshes = [meshes] * T
        if len(meshes) != T:
            raise ValueError(f"expected {T} meshes (one per touch) or a single mesh, got {len(meshes)}")
        touches = [self._setup(m, pos[t], dirs[t], s, p) for t, m in enumerate(meshes)]
        return self._run(touches, s, p)

    # ------------------------------------------------------------------ simulation loop
    def _run(self, touches: list[placement.Placement], s: SensorConfig, p: PressConfig) -> list[TactileReading]:
        """Step the placed touches together until each is done (:class:`~tvrecon.sim.press_run.PressLoop`)."""
        mcfg = self._mpm_config(s, p)
        speed = p.speed if p.speed is not None else float(p.speed_fraction) * self.wave_speed(s)
        return PressLoop(s, p, mcfg, speed, self.device, compile=self.compile).run(touches)
