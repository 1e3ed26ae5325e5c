"""Where the pad goes: ray casts from the pad's footprint, its reach, the default touch point, and the data
pipeline's reachability test.

For every touch the simulation domain ``[0, 1)^3`` is attached to the sensor frame (:func:`sensor_frame`): domain
x, y follow the contact plane and domain -z is the press direction. :func:`place_touch` casts a ray along the press
direction through each contact-layer particle (the pad's *footprint*) and puts the touch point (domain
``(0.5, 0.5, touch_z(dx))``) at the highest hit, so the pad starts ``gap`` cells in front of the first point it will
touch. The rays start :func:`clearance_cells` in front of the touch point; :func:`pad_footprint` gives the data
pipeline the same clearance, so the touches it samples (:func:`pad_reachable`) are the ones the simulator can place.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from torch import Tensor

from tvrecon.sim.bodies import colliders as _colliders
from tvrecon.sim.press.config import PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig, pad_lattice, sensor_frame
from tvrecon.utils.geometry import check_mesh, perpendicular_basis
from tvrecon.utils.shape_check import check_shape

#: Cells beyond the pad's thickness and start gap in front of the touch point where the footprint rays start: the
#: space the pad needs free in front of the surface (shared by :func:`place_touch` and :func:`pad_footprint`).
RAY_START_MARGIN_CELLS = 6.0

#: Cells kept free between the far end of the pad's travel and the domain's edge (:func:`pad_reach`).
REACH_MARGIN_CELLS = 4.0
#: an object more than this many domains across is pressed with a warning (its units are probably wrong)
LARGE_OBJECT_DOMAINS = 10.0


def touch_z(dx: float) -> float:
    """Domain z of the touch plane (the object's highest point under the pad): half-way between two grid node planes.

    The grid contact is decided per node by the sign of the sdf. With the touch plane on a node plane (z = 0.5), the
    nodes along a flat or cylindrical contact line sit at sdf ~ 0, and 0.01-cell geometry (a facet ridge, a tiny
    tilt) flips their sign: the pad would be pushed half a cell early on one stretch of the line only, a bright streak
    (e.g. a lathed can pressed on a facet edge). Half-way between node planes they sit at +-0.5 cells.
    """
    return 0.5 + 0.5 * dx


def clearance_cells(s: SensorConfig, p: PressConfig) -> float:
    """How far in front of the touch point (cells) the footprint rays start: pad thickness + gap + margin."""
    return float(s.thickness) + float(p.gap) + RAY_START_MARGIN_CELLS


def _num(value: object) -> str:
    return f"{float(value.detach()) if isinstance(value, Tensor) else float(value):g}"  # type: ignore[arg-type]


def pad_reach(s: SensorConfig, p: PressConfig) -> float:
    """How far (domain units) the surface may lie from ``position`` along the press axis."""
    dx = 1.0 / int(p.n_grid)
    return 0.5 - (s.thickness + float(p.gap) + float(p.max_depth) + REACH_MARGIN_CELLS) * dx


def host_points(value, name: str, shape: str = "(T, 3)") -> Tensor:
    """``value`` (numbers, a numpy array, a tensor on any device, or a list of those) as a float32 CPU tensor.

    The placement runs on the host (ray casting in numpy), so a touch's position and direction on another device
    than the simulator's, or on different devices from each other, are copied here instead of failing inside torch.

    Raises:
        TypeError: ``value`` holds a string (``'0 0 0.3'``, ``'down'``) or anything else that is not a number, or
            a tensor without values (the meta device); the message names ``name`` and the ``shape`` expected.
    """
    example = "[0, 0, -1]" if shape == "(3,)" else "[[0, 0, -1], ...]"
    items = value if isinstance(value, list | tuple) else [value]
    if isinstance(value, str | bytes) or any(isinstance(v, str | bytes) for v in items):
        raise TypeError(f"{name} must be numbers of shape {shape}, e.g. {example}; got the string {value!r}")
    if any(isinstance(v, Tensor) and v.device.type == "meta" for v in items):
        raise TypeError(f"{name} is a tensor on the meta device (it holds no values): pass numbers of shape {shape}")
    try:
        if isinstance(value, Tensor):
            return value.detach().to(device="cpu", dtype=torch.float32)
        if any(isinstance(v, Tensor) for v in items):
            return torch.stack([torch.as_tensor(v).detach().to(device="cpu", dtype=torch.float32) for v in items])
        return torch.as_tensor(np.asarray(value, dtype=np.float32))
    except (TypeError, ValueError, RuntimeError) as err:
        got = f"{value!r:.120} ({err})"
        raise TypeError(f"{name} must be numbers of shape {shape}, e.g. {example}; got {got}") from None


def as_vec3(value, name: str) -> Tensor:
    """``value`` as a finite (3,) float32 CPU tensor; TypeError / ValueError naming ``name`` otherwise."""
    t = host_points(value, name, "(3,)")
    check_shape(t, "(3,)", name)
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {t.tolist()}")
    return t


@dataclass
class Placement:
    """One touch's scene: sensor frame, domain transform and collider.

    Attributes:
        R: (3, 3) sensor frame, world = R @ local. origin: (3,) world point at the touch point.
        direction: (3,) unit world press direction.
        collider: the object in the domain (``MeshCollider``), None when not reachable.
        reachable: whether the footprint rays met the object within reach (else the press reads nothing).
    """

    R: Tensor
    origin: Tensor
    direction: Tensor
    collider: object | None
    reachable: bool


def place_touch(
    mesh: trimesh.Trimesh, position, direction, s: SensorConfig, p: PressConfig, device: torch.device
) -> Placement:
    """Place the pad at ``position`` pressing along ``direction``: frame, touch point and collider."""
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
    if extent_cells > LARGE_OBJECT_DOMAINS * int(p.n_grid):  # e.g. a CAD part in mm pressed as if in metres
        warnings.warn(
            f"the object is {extent_cells / int(p.n_grid):.3g} domains across (largest extent "
            f"{extent_cells * S / int(p.n_grid):.4g} world units, domain_size {S:g}): the pad, smaller than one "
            f"domain, touches a patch that is flat at this scale. If the mesh is in mm, scale it to metres "
            f"(mesh.apply_scale(1e-3)) or raise domain_size",
            RuntimeWarning,
            stacklevel=3,
        )
    pos = as_vec3(position, "position")
    d = as_vec3(direction, "direction")
    R = sensor_frame(d)  # raises on zero / NaN direction
    d = -R[:, 2]
    reach = pad_reach(s, p)
    if reach <= 0:
        need = s.thickness + float(p.gap) + float(p.max_depth) + REACH_MARGIN_CELLS
        depth = f"; a depth of {_num(p.depth)} cells sets it to {_num(p.depth)} + 0.5" if p.depth is not None else ""
        raise ValueError(
            f"the press does not fit in the domain of n_grid={int(p.n_grid)} (the smallest that fits it is "
            f"{2 * math.ceil(need)}): pad thickness {s.thickness:g} + gap {_num(p.gap)} + max_depth "
            f"{_num(p.max_depth)} (the hand's travel{depth}) + margin {REACH_MARGIN_CELLS:g} = {need:g} cells, more "
            f"than half the domain (n_grid / 2 = {int(p.n_grid) / 2:g} cells). Press less deep (depth / max_depth) "
            f"or raise n_grid"
        )
    # mesh in the sensor frame centred on `position`, in domain units (not yet shifted by 0.5): world = pos + S Rn local
    Rn, pos_w = R.double().numpy(), pos.double().numpy()
    local = (np.asarray(mesh.vertices, dtype=np.float64) - pos_w) @ Rn / S
    # rays from the contact-layer lattice along -z: the first point of the object the pad will touch
    lat = pad_lattice(s)[: s.resolution[0] * s.resolution[1]].double().numpy() * dx
    # rays start a little behind the pad's start (a position slightly inside the object still works)
    back = min(reach, clearance_cells(s, p) * dx)
    origins = np.stack([lat[:, 0], lat[:, 1], np.full(len(lat), back)], axis=1)
    # cast in the object's own frame, on its ray intersector: trimesh builds that Embree scene once per mesh object,
    # so an object's touches share it (a mesh in the touch's frame would build one per touch)
    dirs = np.tile(-Rn[:, 2], (len(lat), 1))
    locs, _, _ = mesh.ray.intersects_location(pos_w + S * origins @ Rn.T, dirs, multiple_hits=False)
    heights = (locs - pos_w) @ Rn[:, 2] / S if len(locs) else np.zeros(0)  # back in the touch's frame
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
        return Placement(R=R, origin=pos, direction=d, collider=None, reachable=False)
    h = float(heights.max())
    origin = pos + R[:, 2] * (h * S)
    zt = touch_z(dx)
    dom = local - np.array([0.0, 0.0, h]) + np.array([0.5, 0.5, zt])
    mdom = trimesh.Trimesh(vertices=dom, faces=np.asarray(mesh.faces), process=False)
    hx, hy = s.half_extent
    travel = float(p.gap) + float(p.max_depth)
    lo = np.array([0.5 - (hx + 3) * dx, 0.5 - (hy + 3) * dx, zt - (travel - float(p.gap) + 3) * dx])
    hi = np.array([0.5 + (hx + 3) * dx, 0.5 + (hy + 3) * dx, zt + (float(p.gap) + 2) * dx])
    # open meshes (walls of zero thickness) are solid behind the first surface the pad meets; `mesh` has the faces of
    # `mdom` (watertightness is topology: trimesh keeps it on `mesh` for the next touch of the same object)
    # the table `collider_refine` times finer than the grid: a part under a grid cell thick is held (PressConfig)
    collider = _colliders.MeshCollider(
        mdom,
        n_grid=int(p.n_grid) * int(p.collider_refine),
        region=(lo, hi),
        device=device,
        from_above=True,
        watertight=mesh.is_watertight,
        # the inside test in the object's frame too (dom + (-0.5, -0.5, h - zt) = local), on the shared intersector
        sign_frame=(mesh, Rn, pos_w + S * Rn @ np.array([-0.5, -0.5, h - zt]), S),
    )
    x_rest = pad_lattice(s, device=device) * dx + torch.tensor([0.5, 0.5, zt + float(p.gap) * dx], device=device)
    inside = collider.count_inside(x_rest)  # no interpolation when no reachable node is inside
    if inside:
        raise ValueError(
            f"the pad would start inside the object ({inside} particles): `direction` {d.tolist()} must point "
            f"into the object from the outside at `position` {pos.tolist()} (e.g. minus the surface normal), or "
            "leave the position out (None; the CLI without --position) to let the simulator place the pad"
        )
    return Placement(R=R, origin=origin, direction=d, collider=collider, reachable=True)


def touch_position(mesh: trimesh.Trimesh, direction, s: SensorConfig, p: PressConfig) -> Tensor:
    """A touch point the pad reaches from outside along ``direction`` (see ``EIPSimulator.touch_position``)."""
    check_mesh(mesh)
    R = sensor_frame(as_vec3(direction, "direction")).double().numpy()
    S, dx = float(p.domain_size), 1.0 / int(p.n_grid)
    centre = np.asarray(mesh.bounds, dtype=np.float64).mean(0)
    local = (np.asarray(mesh.vertices, dtype=np.float64) - centre) @ R / S  # press frame, domain units
    mloc = trimesh.Trimesh(vertices=local, faces=np.asarray(mesh.faces), process=False)
    top = float(local[:, 2].max()) + dx  # outside the bounding box, on the pad's side
    lat = pad_lattice(s)[: s.resolution[0] * s.resolution[1], :2].double().numpy() * dx
    foot = lat  # (HW, 2) the contact particles' columns: the rays `place_touch` casts from the touch point

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


def pad_footprint(s: SensorConfig, p: PressConfig) -> tuple[float, float]:
    """The footprint in world units of a pad ``s`` pressed as ``p`` (a simulator's ``sensor`` and ``cfg``):
    (width, clearance).

    width: diagonal of the contact layer (covers the pad whatever its rotation about the press axis);
    clearance: how far behind the contact point the simulator starts looking for the object
    (:func:`clearance_cells`, as in :func:`place_touch`), i.e. the space the pad needs free in front of the surface.
    """
    cell = float(p.domain_size) / int(p.n_grid)  # world units per grid cell
    hx, hy = s.half_extent
    width = 2.0 * float(np.hypot(hx, hy)) * cell
    clearance = clearance_cells(s, p) * cell
    return width, clearance


def pad_reachable(
    mesh: trimesh.Trimesh, positions: np.ndarray, directions: np.ndarray, width: float, clearance: float, k: int = 7
) -> np.ndarray:
    """Whether a flat pad of diagonal `width` can approach each touch: its footprint disc, lifted `clearance`
    and 2 `clearance` behind the contact point against the press direction, lies outside the object (not in a
    groove, a hole or a concave pocket narrower than the pad).

    Args:
        mesh: the object (watertight: inside/outside by ray parity).
        positions: (N, 3) contact points. directions: (N, 3) unit press directions (into the object).
        width: footprint diameter, world units. clearance: lift, world units.
        k: footprint samples per side (k x k grid clipped to the disc).

    Returns:
        (N,) bool.
    """
    positions = np.asarray(positions, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if len(positions) == 0:
        return np.zeros(0, dtype=bool)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    e1, e2 = perpendicular_basis(d)
    g = np.linspace(-0.5, 0.5, k) * width
    gx, gy = np.meshgrid(g, g)
    disc = np.hypot(gx, gy) <= 0.5 * width + 1e-12
    gx, gy = gx[disc], gy[disc]  # (S,)
    disc_pts = positions[:, None] + gx[None, :, None] * e1[:, None] + gy[None, :, None] * e2[:, None]  # (N, S, 3)
    # two layers: where the simulator starts its rays, and where the pad itself may end up above them
    pts = np.concatenate([disc_pts - lift * clearance * d[:, None] for lift in (1.0, 2.0)], axis=1)  # (N, 2S, 3)
    inside = mesh.contains(pts.reshape(-1, 3)).reshape(len(positions), -1)
    return ~inside.any(axis=1)
