"""The EIP press protocol (paper Algorithm 1): place a sensor pad against a mesh and press until a terminal check.

Coordinates. For every touch the simulation domain ``[0, 1)^3`` (``n_grid`` cells spanning ``domain_size`` world
units) is attached to the *sensor frame* (see :func:`tvrecon.sim.sensor.sensor_frame`): domain x, y follow the
contact plane and domain -z is the press direction, so the pad is aligned with the grid whatever the world
direction. The domain point (0.5, 0.5, 0.5 + dx / 2) is the *touch point*: laterally the given ``position``, along the
press axis the highest point of the object under the pad's footprint (found by ray casting), so the pad starts
``gap`` cells in front of the first point it will touch. World <-> domain::

    u = R^T (w - origin) / domain_size + c        w = origin + R (u - c) domain_size,   c = (0.5, 0.5, 0.5 + dx / 2)

(the touch plane lies half-way between grid node planes, see ``_touch_z``)

Stop rules (checked after every step; the first rule that is configured decides, in this order):
``depth`` (indentation past first contact, cells) > ``force`` (normal contact force) > ``threshold`` (the
terminal check of Algorithm 1, :func:`terminal_chamfer`) ; the hand never travels more than
``gap + max_depth`` cells (or ``max_steps`` steps).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree
from torch import Tensor
from tqdm.auto import tqdm

from tvrecon.config_utils import check_known_keys, field_names
from tvrecon.geometry import check_mesh
from tvrecon.sim import colliders as _colliders
from tvrecon.sim.forces import column_force_field
from tvrecon.sim.materials import p_wave_speed
from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState, cfl_dt
from tvrecon.sim.sensor import SensorConfig, _scalar, alpha_profile, mass_scale, pad_lattice, sensor_frame

#: Default terminal threshold, in squared grid cells per contact-layer particle (see :func:`terminal_chamfer`).
DEFAULT_THRESHOLD = 0.05


@dataclass
class PressConfig:
    """How a touch is simulated.

    Attributes:
        n_grid: grid cells across the domain (dx = 1 / n_grid in domain units).
        domain_size: world units spanned by the domain (the mesh is scaled by 1 / domain_size).
        gap: start gap between the contact layer and the object's highest point under the pad, in cells. The grid
            contact reaches the node plane 1.5 cells below the particles; with the touch plane half-way between node
            planes (``_touch_z``) the default 1.0 is the smallest gap that starts out of contact, and the first
            step already touches (no approach steps). Below 1.0 the pad starts in grid contact.
        speed: hand speed v_r in domain units / s; None -> ``speed_fraction`` * elastic (P-)wave speed.
        speed_fraction: fraction of the P-wave speed sqrt((lambda + 2 mu) / rho) used when ``speed`` is None.
        threshold: :func:`terminal_chamfer` threshold (squared cells per contact particle); the default stop rule.
        depth: stop at this indentation past first contact (cells); overrides ``force`` and ``threshold``.
        force: stop when the normal contact force reaches this (simulation units); overrides ``threshold``.
        max_depth: the hand never travels more than ``gap + max_depth`` cells (also bounds the collider region).
        max_steps: hard step limit of the press phase; None -> the steps needed for ``gap + max_depth``.
        friction: Coulomb friction coefficient on collider nodes.
        dt: time step; None -> CFL rule of the solver (``cfl_dt``).
        release_steps: after pressing, retract the hand at ``speed`` (back to its start) and hold, for this
            many steps in total; the reading then carries the ``residual`` image.
        record_every: record the tactile image and the pad particles every this many steps (0 = off).
        progress: show a tqdm progress bar over the steps.
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

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ValueError naming the bad field."""
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
            :mod:`tvrecon.sim.forces`.
        contact: whether the object ever pushed on the pad.
        frame: (3, 3) float32 sensor frame R (columns e_x, e_y, e_z in world), world = R @ local.
        origin: (3,) float32 world point at the touch point (domain (0.5, 0.5, 0.5 + dx / 2)).
        residual: (3, H, W) image after the release phase, or None without release.
        frames: (K, 3, H, W) recorded images (``record_every``), or None.
        frame_steps: the K step indices of ``frames``.
        particles: (K, P, 3) recorded pad particle positions in world coordinates, or None.
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


def terminal_chamfer(x: Tensor, x0: Tensor, lattice: tuple[int, int, float] | None = None) -> float:
    """Terminal check of Algorithm 1, paper eq. 12 (eq:chamfer): the centred contact layer now vs at rest.

    ``l = mean_p min_q |x^_p - x^0_q|^2 + mean_q min_p |x^_p - x^0_q|^2`` with ``x^ = x - mean(x)``; the paper sums,
    we average (divide by |S|) so the threshold does not depend on the tactile resolution. Not differentiable
    (it only drives the terminal check).

    Args:
        x: (N, 3) contact layer now, in cells. x0: (N, 3) at rest, in cells.
        lattice: (H, W, spacing) when ``x0`` is the planar rest lattice of :func:`pad_lattice` (z constant); the
            first term is then exact by rounding to the lattice instead of a k-d tree query.
    Returns:
        the chamfer value in squared cells.
    """
    a_t = (x - x.mean(0)).detach()
    b = (x0 - x0.mean(0)).detach().cpu().double().numpy()
    a = a_t.cpu().double().numpy()
    if lattice is not None:
        H, W, sp = lattice
        j = np.clip(np.rint(a[:, 0] / sp + (W - 1) / 2), 0, W - 1)
        i = np.clip(np.rint(a[:, 1] / sp + (H - 1) / 2), 0, H - 1)
        d_ab2 = (a[:, 0] - (j - (W - 1) / 2) * sp) ** 2 + (a[:, 1] - (i - (H - 1) / 2) * sp) ** 2 + a[:, 2] ** 2
    else:
        d_ab, _ = cKDTree(b).query(a, workers=1)
        d_ab2 = d_ab**2
    d_ba, _ = cKDTree(a).query(b, workers=1)
    return float(d_ab2.mean() + (d_ba**2).mean())


#: Deprecated alias of :func:`terminal_chamfer` (same object; the paper numbers the equation 12, not 13).
chamfer_eq13 = terminal_chamfer


def chamfer_reaches(x: Tensor, x0: Tensor, lattice: tuple[int, int, float], threshold: float) -> bool:
    """Whether ``terminal_chamfer(x, x0, lattice) >= threshold``, usually without a k-d tree.

    The second chamfer term (rest lattice -> nearest particle) is at most the mean squared distance of each rest
    point to *its own* particle (same index, both centred), so when the exact first term plus that bound stays
    below the threshold the answer is False; only otherwise is the exact value computed. Same result as comparing
    :func:`terminal_chamfer`, at a fraction of the cost per step.

    Args:
        x: (N, 3) contact layer now, in cells. x0: (N, 3) planar rest lattice, in cells.
        lattice: (H, W, spacing) of ``x0``. threshold: squared cells per particle.
    """
    a = (x - x.mean(0)).detach()
    b = (x0 - x0.mean(0)).detach().to(a)
    H, W, sp = lattice
    j = torch.clamp(torch.round(a[:, 0] / sp + (W - 1) / 2), 0, W - 1)
    i = torch.clamp(torch.round(a[:, 1] / sp + (H - 1) / 2), 0, H - 1)
    d_ab2 = (a[:, 0] - (j - (W - 1) / 2) * sp) ** 2 + (a[:, 1] - (i - (H - 1) / 2) * sp) ** 2 + a[:, 2] ** 2
    upper = float(d_ab2.mean() + ((a - b) ** 2).sum(1).mean())
    if upper < float(threshold) * (1.0 - 1e-6):
        return False
    return terminal_chamfer(x, x0, lattice) >= float(threshold)


def _touch_z(dx: float) -> float:
    """Domain z of the touch plane (the object's highest point under the pad): half-way between two grid node planes.

    The grid contact is decided per node by the sign of the sdf. With the touch plane on a node plane (z = 0.5), the
    nodes along a flat or cylindrical contact line sit at sdf ~ 0, and 0.01-cell geometry (a facet ridge, a tiny
    tilt) flips their sign: the pad would be pushed half a cell early on one stretch of the line only, a bright streak
    (e.g. a lathed can pressed on a facet edge). Half-way between node planes they sit at +-0.5 cells.
    """
    return 0.5 + 0.5 * dx


def _as_vec3(value, name: str) -> Tensor:
    t = torch.as_tensor(np.asarray(value, dtype=np.float32) if not isinstance(value, Tensor) else value)
    t = t.detach().to(torch.float32).cpu()
    if t.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {t.tolist()}")
    return t


@dataclass
class _Touch:
    """Per-touch scene: frame, domain transform, collider and bookkeeping (internal)."""

    R: Tensor  # (3, 3) sensor frame
    origin: Tensor  # (3,) world point at the domain centre
    direction: Tensor  # (3,) unit world press direction
    collider: object | None
    reachable: bool
    # bookkeeping during the loop
    phase: str = "press"  # press -> release -> done
    steps: int = 0
    release_left: int = 0
    retract_left: int = 0
    travel: float = 0.0  # hand travel along -z in cells (press minus retract)
    disp: Tensor | None = None  # (3,) differentiable hand displacement in domain units
    contact: bool = False
    force_hist: list[float] = field(default_factory=list)
    reading: TactileReading | None = None
    frames: list[Tensor] = field(default_factory=list)
    frame_steps: list[int] = field(default_factory=list)
    particles: list[Tensor] = field(default_factory=list)


class EIPSimulator:
    """Press a sensor pad onto meshes with MLS-MPM and read the tactile images.

    Args:
        sensor: pad geometry and material (default :class:`SensorConfig`).
        press: press protocol (default :class:`PressConfig`).
        device: torch device of the simulation.
    """

    def __init__(
        self, sensor: SensorConfig | None = None, press: PressConfig | None = None, device: torch.device | str = "cpu"
    ) -> None:
        self.sensor = sensor if sensor is not None else SensorConfig()
        self.cfg = press if press is not None else PressConfig()
        self.device = torch.device(device)

    # ------------------------------------------------------------------ configuration
    def _configs(self, overrides: dict) -> tuple[SensorConfig, PressConfig]:
        s_names, p_names = set(field_names(SensorConfig)), set(field_names(PressConfig))
        check_known_keys(overrides, s_names | p_names, "press")
        s = dataclasses.replace(self.sensor, **{k: v for k, v in overrides.items() if k in s_names})
        p = dataclasses.replace(self.cfg, **{k: v for k, v in overrides.items() if k in p_names})
        if p.depth is not None and float(p.depth) + 0.5 > float(p.max_depth):
            p = dataclasses.replace(p, max_depth=float(p.depth) + 0.5)  # a requested depth extends the travel limit
        return s, p

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
        )
        if cfg.dt is None:
            probe = MPMConfig(n_grid=int(p.n_grid), E=_scalar(s.E), nu=_scalar(s.nu), rho=float(s.rho))
            cfg.dt = float(cfl_dt(probe))
        return cfg

    # ------------------------------------------------------------------ scene set-up
    def _reach(self, s: SensorConfig, p: PressConfig) -> float:
        """How far (domain units) the surface may lie from ``position`` along the press axis."""
        dx = 1.0 / int(p.n_grid)
        return 0.5 - (s.thickness + float(p.gap) + float(p.max_depth) + 4.0) * dx

    def _setup(self, mesh: trimesh.Trimesh, position, direction, s: SensorConfig, p: PressConfig) -> _Touch:
        check_mesh(mesh)
        S, dx = float(p.domain_size), 1.0 / int(p.n_grid)
        extent_cells = float(np.ptp(np.asarray(mesh.bounds), axis=0).max()) / S * int(p.n_grid)
        if extent_cells < 1.0:  # the collider samples the object at grid nodes: below a cell it falls between them
            raise ValueError(
                f"the object is {extent_cells:.3g} grid cells across (largest extent "
                f"{extent_cells * S / int(p.n_grid):.3g} world units, one cell = domain_size/n_grid = "
                f"{S / int(p.n_grid):.3g}): the pad would miss it. Scale the object up, or lower domain_size (the pad "
                f"shrinks with it) or raise n_grid so it spans several cells"
            )
        pos = _as_vec3(position, "position")
        d = _as_vec3(direction, "direction")
        R = sensor_frame(d)  # raises on zero / NaN direction
        d = -R[:, 2]
        reach = self._reach(s, p)
        if reach <= 0:
            raise ValueError(f"the domain ({p.n_grid} cells) is too small for a pad of thickness {s.thickness} cells")
        # mesh in the sensor frame centred on `position`, in domain units (not yet shifted by 0.5)
        Rn = R.double().numpy()
        local = (np.asarray(mesh.vertices, dtype=np.float64) - pos.double().numpy()) @ Rn / S
        mloc = trimesh.Trimesh(vertices=local, faces=np.asarray(mesh.faces), process=False)
        # rays from the contact-layer lattice along -z: the first point of the object the pad will touch
        lat = pad_lattice(s)[: s.resolution[0] * s.resolution[1]].double().numpy() * dx
        # rays start a little behind the pad's start (a position slightly inside the object still works)
        back = min(reach, (s.thickness + float(p.gap) + 6.0) * dx)
        origins = np.stack([lat[:, 0], lat[:, 1], np.full(len(lat), back)], axis=1)
        dirs = np.tile(np.array([0.0, 0.0, -1.0]), (len(lat), 1))
        locs, _, _ = mloc.ray.intersects_location(origins, dirs, multiple_hits=False)
        heights = locs[:, 2] if len(locs) else np.zeros(0)
        heights = heights[heights >= -reach]
        if len(heights) == 0:
            closest, dist, _ = trimesh.proximity.closest_point(mesh, pos.double().numpy()[None])
            dist_w = float(dist[0])
            if dist_w > reach * S:
                raise ValueError(
                    f"position {pos.tolist()} is {dist_w:.3g} world units from the object's surface, but the pad can "
                    f"reach at most {reach * S:.3g} (half the domain_size {S} minus the pad and its travel): pass a "
                    "point on or near the surface, or a larger domain_size"
                )
            return _Touch(R=R, origin=pos, direction=d, collider=None, reachable=False)
        h = float(heights.max())
        origin = pos + R[:, 2] * (h * S)
        zt = _touch_z(dx)
        dom = local - np.array([0.0, 0.0, h]) + np.array([0.5, 0.5, zt])
        mdom = trimesh.Trimesh(vertices=dom, faces=np.asarray(mesh.faces), process=False)
        hx, hy = s.half_extent
        travel = float(p.gap) + float(p.max_depth)
        lo = np.array([0.5 - (hx + 3) * dx, 0.5 - (hy + 3) * dx, zt - (travel - float(p.gap) + 3) * dx])
        hi = np.array([0.5 + (hx + 3) * dx, 0.5 + (hy + 3) * dx, zt + (float(p.gap) + 2) * dx])
        # open meshes (walls of zero thickness) are solid behind the first surface the pad meets
        collider = _colliders.MeshCollider(
            mdom, n_grid=int(p.n_grid), region=(lo, hi), device=self.device, from_above=True
        )
        x_rest = pad_lattice(s, device=self.device) * dx + torch.tensor(
            [0.5, 0.5, zt + float(p.gap) * dx], device=self.device
        )
        inside = int((collider.sdf(x_rest) < 0).sum())
        if inside:
            raise ValueError(
                f"the pad would start inside the object ({inside} particles): `direction` {d.tolist()} must point "
                f"into the object from the outside at `position` {pos.tolist()} (e.g. minus the surface normal), or "
                "leave the position out (None; the CLI without --position) to let the simulator place the pad"
            )
        return _Touch(R=R, origin=origin, direction=d, collider=collider, reachable=True)

    # ------------------------------------------------------------------ public API
    def touch_position(self, mesh: trimesh.Trimesh, direction, **overrides) -> Tensor:
        """A touch point the pad reaches from outside along ``direction``: the placement when none is given.

        The pad's footprint (its contact-layer particles, in the press frame) is centred on the line along
        ``direction`` through the centre of the mesh's bounding box. A ray along ``direction`` from outside the
        bounding box through each footprint particle meets the object's first surface; the touch
        point is on the centre line at the highest of these hits (the first point the pad will touch), so the pad
        starts clear of the object however much the surface rises under it. When every ray misses (e.g. the hole
        of a torus), the footprint moves so that its most central particle is over the hit nearest the centre line
        among rays cast over the whole bounding box. (The data pipeline samples its own touches, see
        ``tvrecon.data.touches``.)

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
        check_mesh(mesh)
        R = sensor_frame(_as_vec3(direction, "direction")).double().numpy()
        S, dx = float(p.domain_size), 1.0 / int(p.n_grid)
        centre = np.asarray(mesh.bounds, dtype=np.float64).mean(0)
        local = (np.asarray(mesh.vertices, dtype=np.float64) - centre) @ R / S  # press frame, domain units
        mloc = trimesh.Trimesh(vertices=local, faces=np.asarray(mesh.faces), process=False)
        top = float(local[:, 2].max()) + dx  # outside the bounding box, on the pad's side
        lat = pad_lattice(s)[: s.resolution[0] * s.resolution[1], :2].double().numpy() * dx
        foot = lat  # (HW, 2) the contact particles' columns: the rays `_setup` casts from the touch point

        def first_hits(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """(K, 2) ray columns -> (K,) height of the first surface met from above (-inf: miss), hit points."""
            origins = np.concatenate([xy, np.full((len(xy), 1), top)], axis=1)
            dirs = np.tile(np.array([0.0, 0.0, -1.0]), (len(xy), 1))
            locs, idx, _ = mloc.ray.intersects_location(origins, dirs, multiple_hits=False)
            z = np.full(len(xy), -np.inf)
            if len(idx):
                np.maximum.at(z, idx, locs[:, 2])
            return z, locs

        cxy = np.zeros(2)
        z, _ = first_hits(foot)
        if not np.isfinite(z).any():  # the footprint sees only a hole: move it to the hit nearest the centre line
            lo, hi = local[:, :2].min(0), local[:, :2].max(0)
            n = np.clip(np.ceil((hi - lo) / (float(s.spacing) * dx)).astype(int) + 1, 2, 96)
            gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n[0]), np.linspace(lo[1], hi[1], n[1]), indexing="ij")
            _, locs = first_hits(np.stack([gx.ravel(), gy.ravel()], 1))
            if len(locs) == 0:
                raise ValueError(
                    f"no ray along the direction {np.asarray(direction, dtype=float).tolist()} meets the mesh (it is "
                    "seen edge-on or is thinner than the pad's particle spacing along it, e.g. a flat plane pressed "
                    "along itself): choose a direction that points into the "
                    "object's surface, or give a position"
                )
            # the contact particle nearest the pad's centre goes over that hit
            cxy = locs[np.argmin(np.linalg.norm(locs[:, :2], axis=1)), :2] - lat[np.argmin(np.linalg.norm(lat, axis=1))]
            z, _ = first_hits(foot + cxy)
            if not np.isfinite(z).any():
                z = np.array([float(locs[:, 2].max())])
        touch = np.array([cxy[0], cxy[1], float(z.max())])
        return torch.as_tensor(centre + R @ touch * S, dtype=torch.float32)

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
    def _run(self, touches: list[_Touch], s: SensorConfig, p: PressConfig) -> list[TactileReading]:
        dev = self.device
        H, W = s.resolution
        HW, dx = H * W, 1.0 / int(p.n_grid)
        mcfg = self._mpm_config(s, p)
        dt = float(mcfg.dt)
        speed = p.speed if p.speed is not None else float(p.speed_fraction) * self.wave_speed(s)
        speed_t = torch.as_tensor(speed, dtype=torch.float32, device=dev)
        step_cells = _scalar(speed) * dt / dx
        max_steps = (
            p.max_steps if p.max_steps is not None else math.ceil((float(p.gap) + float(p.max_depth)) / step_cells)
        )
        down = torch.tensor([0.0, 0.0, -1.0], device=dev)

        lat = pad_lattice(s, device=dev)  # (P, 3) cells
        P = lat.shape[0]
        x_rest = lat * dx + torch.tensor([0.5, 0.5, _touch_z(dx) + float(p.gap) * dx], device=dev)  # (P, 3) domain
        alpha1 = alpha_profile(s, device=dev)  # (P,)
        vol = (float(s.spacing) * dx) ** 3
        zero_img = torch.zeros(3, H, W, dtype=torch.float32, device=dev)

        active = [t for t, tc in enumerate(touches) if tc.reachable]
        for tc in touches:
            if not tc.reachable:
                tc.reading = self._reading(tc, zero_img, s, p, chamfer=0.0, force=torch.zeros(3), x_pad=None)
                tc.reading.contact = False
                tc.reading.force_field = torch.zeros(H, W, 3)
        if not active:
            return [tc.reading for tc in touches]  # type: ignore[misc]

        for t in active:
            touches[t].disp = torch.zeros(3, device=dev, dtype=torch.float32)
            touches[t].release_left = int(p.release_steps)
        B = len(active)
        v0 = (speed_t * down).expand(B * P, 3)  # the pad starts moving rigidly with the hand: zero stress
        state = ParticleState.create(
            x_rest.repeat(B, 1),
            v0.clone() if not v0.requires_grad else v0 + 0.0,
            volume=torch.full((B * P,), vol, device=dev),
            rho=float(s.rho),
            batch=torch.arange(B, device=dev).repeat_interleave(P),
        )
        # the back layer is glued to the rigid, heavy mount (see SensorConfig.mount_mass)
        state = dataclasses.replace(state, mass=state.mass * mass_scale(s, device=dev).repeat(B))
        solver = MLSMPM(mcfg, device=dev)
        x0_contact = x_rest[:HW] / dx  # (HW, 3) cells
        total = max_steps + int(p.release_steps)
        bar = tqdm(total=total * len(active), desc="EIP press", disable=not p.progress, leave=False)
        n = 0
        while active:
            n += 1
            if n > total + 1:
                raise RuntimeError("press loop did not terminate (internal error)")
            B = len(active)
            signs = []
            for t in active:
                tc = touches[t]
                if tc.phase == "press":
                    signs.append(1.0)
                elif tc.retract_left > 0:
                    signs.append(-1.0)
                else:
                    signs.append(0.0)
            sign_t = torch.tensor(signs, device=dev)  # (B,)
            v_touch = sign_t[:, None] * speed_t * down  # (B, 3)
            hv = v_touch.repeat_interleave(P, dim=0)  # (B * P, 3)
            state = solver.step(
                state, collider=[touches[t].collider for t in active], hand_velocity=hv, alpha=alpha1.repeat(B)
            )
            xb = state.x.view(B, P, 3)
            if not bool(torch.isfinite(xb[:, :HW]).all()):
                raise FloatingPointError(
                    f"simulation diverged at step {n} (non-finite particle positions): lower PressConfig.dt or speed, "
                    f"or raise damping; current dt={dt:.3g}, speed={_scalar(speed):.3g}, E={_scalar(s.E):.3g}"
                )
            force = solver.last_force.detach()  # (B, 3) on the pad, domain axes
            particle_force = None  # (B, P, 3), computed on the first stop of this step
            done_now = []
            for b, t in enumerate(active):
                tc = touches[t]
                tc.disp = tc.disp + v_touch[b] * dt
                tc.travel += signs[b] * step_cells
                fz = float(force[b, 2])
                if tc.phase == "press":
                    tc.steps += 1
                    tc.force_hist.append(fz)
                    if fz > 0:
                        tc.contact = True
                    if p.record_every and tc.steps % int(p.record_every) == 0:
                        self._record(tc, xb[b], x0_contact, dx, s, p)
                    if self._should_stop(tc, xb[b, :HW] / dx, x0_contact, (H, W, float(s.spacing)), max_steps, p):
                        img = self._image(xb[b, :HW], tc.disp, x_rest[:HW], dx, H, W)
                        ch = terminal_chamfer(xb[b, :HW] / dx, x0_contact, (H, W, float(s.spacing)))
                        f_world = tc.R @ force[b].cpu()
                        tc.reading = self._reading(tc, img, s, p, chamfer=ch, force=f_world, x_pad=xb[b])
                        if particle_force is None:
                            particle_force = solver.last_particle_force(state.mass).view(B, P, 3)
                        tc.reading.force_field = (
                            column_force_field(particle_force[b], (H, W), int(s.layers)).float().cpu()
                        )
                        _warn_if_passed_through(tc, p)
                        if p.record_every and tc.steps % int(p.record_every) != 0:
                            self._record(tc, xb[b], x0_contact, dx, s, p)
                        if tc.release_left > 0:
                            tc.phase = "release"
                            tc.retract_left = tc.steps
                        else:
                            tc.phase = "done"
                elif tc.phase == "release":
                    tc.release_left -= 1
                    tc.retract_left = max(tc.retract_left - 1, 0) if signs[b] < 0 else tc.retract_left
                    if p.record_every and (int(p.release_steps) - tc.release_left) % int(p.record_every) == 0:
                        self._record(tc, xb[b], x0_contact, dx, s, p)
                    if tc.release_left <= 0:
                        assert tc.reading is not None
                        tc.reading.residual = self._image(xb[b, :HW], tc.disp, x_rest[:HW], dx, H, W)
                        tc.phase = "done"
                if tc.phase == "done":
                    done_now.append(b)
            bar.update(B)
            if done_now:
                keep_b = [b for b in range(B) if b not in done_now]
                for b in done_now:
                    self._finish(touches[active[b]])
                active = [active[b] for b in keep_b]
                if active:
                    state = _select_blocks(state, keep_b, P)
        bar.close()
        return [tc.reading for tc in touches]  # type: ignore[misc]

    @staticmethod
    def _should_stop(
        tc: _Touch, contact_cells: Tensor, x0_contact: Tensor, lattice: tuple, max_steps: int, p: PressConfig
    ) -> bool:
        if tc.steps >= max_steps or tc.travel >= float(p.gap) + float(p.max_depth) - 1e-6:
            return True
        if p.depth is not None:
            return tc.travel - float(p.gap) >= float(p.depth) - 1e-6
        if p.force is not None:
            recent = tc.force_hist[-3:]
            return sum(recent) / len(recent) >= float(p.force)
        if p.threshold is not None and tc.contact:
            return chamfer_reaches(contact_cells, x0_contact, lattice, float(p.threshold))
        return False

    @staticmethod
    def _image(x_contact: Tensor, disp: Tensor, rest_contact: Tensor, dx: float, H: int, W: int) -> Tensor:
        """(HW, 3) domain positions -> (3, H, W) displacement in cells with the hand translation removed."""
        u = (x_contact - rest_contact - disp) / dx  # (HW, 3); domain axes are the sensor axes
        return u.reshape(H, W, 3).permute(2, 0, 1).contiguous()

    def _to_world(self, tc: _Touch, u: Tensor, p: PressConfig) -> Tensor:
        """(N, 3) domain -> (N, 3) world."""
        c = torch.tensor([0.5, 0.5, _touch_z(1.0 / int(p.n_grid))], dtype=u.dtype, device=u.device)
        return tc.origin.to(u.device) + (u - c) * float(p.domain_size) @ tc.R.to(u.device).T

    def _record(self, tc: _Touch, x_pad: Tensor, x0c: Tensor, dx: float, s: SensorConfig, p: PressConfig) -> None:
        H, W = s.resolution
        rest = x0c * dx
        tc.frames.append(self._image(x_pad[: H * W].detach(), tc.disp.detach(), rest, dx, H, W))
        tc.frame_steps.append(tc.steps + (int(p.release_steps) - tc.release_left if tc.phase == "release" else 0))
        tc.particles.append(self._to_world(tc, x_pad.detach(), p).cpu())

    def _reading(
        self, tc: _Touch, img: Tensor, s: SensorConfig, p: PressConfig, chamfer: float, force: Tensor, x_pad
    ) -> TactileReading:
        dx = 1.0 / int(p.n_grid)
        disp = tc.disp.detach().cpu() if tc.disp is not None else torch.zeros(3)
        centre = torch.tensor([0.5, 0.5, _touch_z(dx) + float(p.gap) * dx]) + disp
        return TactileReading(
            image=img,
            position=self._to_world(tc, centre[None], p)[0].to(torch.float32),
            direction=tc.direction.clone(),
            steps=tc.steps,
            depth=max(0.0, tc.travel - float(p.gap)),
            chamfer=float(chamfer),
            force=force.to(torch.float32),
            contact=tc.contact,
            frame=tc.R.clone(),
            origin=tc.origin.clone(),
        )

    @staticmethod
    def _finish(tc: _Touch) -> None:
        if tc.reading is None:
            return
        if tc.frames:
            tc.reading.frames = torch.stack(tc.frames)
            tc.reading.frame_steps = list(tc.frame_steps)
            tc.reading.particles = torch.stack(tc.particles)


def _warn_if_passed_through(tc: _Touch, p: PressConfig) -> None:
    """Warn when the pad went a cell or more past the surface found under its footprint without feeling it.

    The rays of ``_setup`` saw the object under the pad, so a press without contact means the grid did not resolve
    what the rays hit (a feature thinner than a cell between the nodes): not a clean miss.
    """
    past = tc.travel - float(p.gap)
    if tc.reachable and not tc.contact and past >= 1.0 - 1e-6:
        warnings.warn(
            f"the pad went {past:.2f} cells past the object's surface under its footprint (touch point "
            f"{[round(v, 4) for v in tc.origin.tolist()]}) without touching it: the object is thinner there than the "
            f"grid resolves. Raise n_grid or lower domain_size so the part spans several cells, or press elsewhere",
            RuntimeWarning,
            stacklevel=4,
        )


def _select_blocks(state: ParticleState, keep: list[int], P: int) -> ParticleState:
    """Keep the particle blocks ``keep`` (each P particles) and renumber their batch index 0..len(keep)-1."""
    dev = state.x.device
    idx = (torch.tensor(keep, device=dev)[:, None] * P + torch.arange(P, device=dev)).reshape(-1)
    out = {}
    for f in dataclasses.fields(state):
        val = getattr(state, f.name)
        out[f.name] = (
            val[idx] if isinstance(val, Tensor) and val.ndim >= 1 and val.shape[0] == state.x.shape[0] else val
        )
    out["batch"] = torch.arange(len(keep), device=dev).repeat_interleave(P)
    return dataclasses.replace(state, **out)
