"""TactileFinger: an EIP sensor pad carried by any pybullet body link, pressed by that link's real contacts.

At each :meth:`TactileFinger.sense` the link's pybullet contacts with registered objects (getContactPoints:
position on the object, normal, penetration, normal force) set up an EIP press of the pad against the object's own
mesh at its current pose (body frame -> world): the press is centred on the force-weighted contact point, goes along
the pad's normal (the finger's closing direction, fixed in the link frame) and indents by the penetration plus the
pad's elastic give under the measured force. The tactile image is returned in the *finger's* pad frame (rows along
the link's ``up_axis``, columns ``up x normal``), so two fingers with mirrored link frames see mirrored images.

Presses are cached: the pad is re-simulated only when the contact starts, moves on the object, changes depth by a
set fraction, or the caller asks (e.g. once per control phase). Without contact the pad is at rest: zero image,
``contact=False``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
import torch
import torch.nn.functional as F
import trimesh

__all__ = ["PadConfig", "FingerReading", "LazySimulator", "TactileFinger", "sense_fingers", "to_pad_frame"]


@dataclass
class PadConfig:
    """Physical pad and press settings of a :class:`TactileFinger`.

    resolution: (H, W) tactile pixels; pad_size: physical width of the contact layer in metres (2 cm default).
    n_grid: MPM grid cells across the press domain (the domain spans ``n_grid * dx`` metres, dx = pad cell size).
    stiffness: N/m of the pad's elastic give (indentation = max(penetration, force / stiffness)).
    min_depth, max_depth: clamp of the indentation in metres.
    min_force: total normal force (N) below which the finger counts as not touching.
    move_tol: re-simulate when the contact point moves more than this on the object (metres).
    depth_tol: re-simulate when the indentation changes by more than this fraction.
    E, nu, layers: pad material / thickness passed to the EIP simulator.
    """

    resolution: tuple[int, int] = (24, 24)
    pad_size: float = 0.02
    n_grid: int = 64
    layers: int = 4
    E: float = 3.0
    nu: float = 0.25
    stiffness: float = 2.5e4
    min_depth: float = 2.0e-4
    max_depth: float = 2.5e-3
    min_force: float = 0.05
    move_tol: float = 0.003
    depth_tol: float = 0.35
    max_steps: int = 400

    @property
    def dx(self) -> float:
        """Grid cell size in metres (the pad spans (W - 1) * 0.5 cells)."""
        return self.pad_size / ((max(self.resolution) - 1) * 0.5)

    @property
    def domain_size(self) -> float:
        """World metres spanned by the press domain (``PressConfig.domain_size``)."""
        return self.n_grid * self.dx


@dataclass
class FingerReading:
    """One tactile reading of a finger.

    image: (3,H,W) float32 pad-frame displacement in grid cells (x shear, y shear, z normal; z > 0 into the pad).
    contact: True if the link touches a registered object with at least ``min_force``.
    force: total pybullet normal force (N); force_vec: (3,) float64 world force the object exerts on the finger.
    position: (3,) float64 world contact point (force-weighted, on the object); nan without contact.
    direction: (3,) float64 unit world press direction (the pad normal, into the object).
    penetration: max pybullet penetration (m, >= 0); depth: indentation used for the press (m).
    body: the touched object's body id (-1 = none); simulated: True if this call ran a new EIP press.
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


class LazySimulator:
    """An EIP simulator for a :class:`PadConfig`, built on the first press (so a scene without contact never loads
    the solver). Share one instance between fingers so their presses can be batched."""

    def __init__(self, pad: PadConfig) -> None:
        self.pad = pad
        self._sim = None

    @property
    def sim(self) -> object:
        """The ``tvrecon.sim.press.EIPSimulator`` (pad resolution, 0.5-cell spacing, domain sized from the pad)."""
        if self._sim is None:
            from tvrecon.sim.press import EIPSimulator, PressConfig
            from tvrecon.sim.sensor import SensorConfig

            pc = self.pad
            sensor = SensorConfig(resolution=tuple(pc.resolution), layers=pc.layers, spacing=0.5, E=pc.E, nu=pc.nu)
            press = PressConfig(n_grid=pc.n_grid, domain_size=pc.domain_size, max_steps=pc.max_steps)
            self._sim = EIPSimulator(sensor=sensor, press=press)
        return self._sim

    def press(self, mesh: trimesh.Trimesh, position: object, direction: object, **overrides: object) -> object:
        """``EIPSimulator.press``."""
        return self.sim.press(mesh, position, direction, **overrides)

    def press_batch(self, meshes: object, positions: object, directions: object, **overrides: object) -> list:
        """``EIPSimulator.press_batch``."""
        return self.sim.press_batch(meshes, positions, directions, **overrides)


def to_pad_frame(image: torch.Tensor, direction: np.ndarray, up: np.ndarray) -> torch.Tensor:
    """Resample a simulator tactile image from the simulator's sensor frame into a finger pad frame.

    The simulator frame (``tvrecon.sim.sensor.sensor_frame``) has e_z = -direction and e_x from the world x axis;
    the pad frame shares e_z and has e_y along ``up`` (projected onto the contact plane), e_x = e_y x e_z. Pixels
    are bilinearly resampled (zeros outside the pad) and the shear channels rotated with the frame.

    Args:
        image: (3,H,W) float32 tactile image in the simulator's sensor frame.
        direction: (3,) press direction in world coordinates.
        up: (3,) the pad's "up" axis in world coordinates (not parallel to ``direction``).

    Returns:
        (3,H,W) float32 image in the pad frame.
    """
    from tvrecon.sim.sensor import sensor_frame

    if image.ndim != 3 or image.shape[0] != 3:
        raise ValueError(f"image must be (3,H,W), got {tuple(image.shape)}")
    R = sensor_frame(torch.as_tensor(np.asarray(direction, dtype=np.float32)))  # (3,3) columns ex, ey, ez
    ex, ey, ez = R[:, 0].double(), R[:, 1].double(), R[:, 2].double()
    u = torch.as_tensor(np.asarray(up, dtype=np.float64))
    u = u - (u @ ez) * ez
    if float(torch.linalg.vector_norm(u)) < 1e-6:
        raise ValueError("pad up axis is parallel to the press direction: choose an up axis in the pad plane")
    u = u / torch.linalg.vector_norm(u)
    ex_pad = torch.linalg.cross(u, ez)
    c, s = float(ex_pad @ ex), float(ex_pad @ ey)  # pad x axis in sim coordinates: (cos t, sin t)
    _, H, W = image.shape
    # pad pixel local (x', y') -> sim local (x' c - y' s, x' s + y' c); normalized coords scale x by (W-1)/2 pixels
    jj = torch.linspace(-1.0, 1.0, W, dtype=torch.float64) * (W - 1) / 2
    ii = torch.linspace(-1.0, 1.0, H, dtype=torch.float64) * (H - 1) / 2
    yy, xx = torch.meshgrid(ii, jj, indexing="ij")  # (H,W) pad-frame pixel offsets
    xs, ys = xx * c - yy * s, xx * s + yy * c
    grid = torch.stack([xs / ((W - 1) / 2), ys / ((H - 1) / 2)], dim=-1)[None].to(image.dtype)  # (1,H,W,2)
    out = F.grid_sample(image[None], grid.to(image.device), mode="bilinear", padding_mode="zeros", align_corners=True)
    out = out[0]
    sx, sy = out[0].clone(), out[1].clone()
    out[0] = sx * c + sy * s
    out[1] = -sx * s + sy * c
    return out


class TactileFinger:
    """An EIP pad on a pybullet link.

    Args:
        body: pybullet body unique id carrying the pad (e.g. the robot).
        link: link index of the finger (-1 = base).
        normal_axis: (3,) pad press direction in the link frame (the finger's closing direction).
        up_axis: (3,) pad "up" axis in the link frame (image rows), e.g. along the finger towards its tip.
        pad_center: (3,) centre of the pad's contact face in the link frame; the press is then centred on the pad
            (the contact plane point in front of it), so the image shows where on the pad the object touches.
            None centres the press on the force-weighted contact point instead.
        pad: pad geometry and caching thresholds.
        simulator: a ``tvrecon.sim.press.EIPSimulator``; None builds one from ``pad``.
        client: pybullet physics client id.
        name: label used in logs.
    """

    def __init__(
        self,
        body: int,
        link: int,
        normal_axis: Sequence[float],
        up_axis: Sequence[float] = (0.0, 0.0, 1.0),
        pad_center: Sequence[float] | None = None,
        pad: PadConfig | None = None,
        simulator: object | None = None,
        client: int = 0,
        name: str = "finger",
    ) -> None:
        n = np.asarray(normal_axis, dtype=np.float64)
        u = np.asarray(up_axis, dtype=np.float64)
        if n.shape != (3,) or u.shape != (3,):
            raise ValueError(f"normal_axis and up_axis must be (3,), got {n.shape} and {u.shape}")
        if np.linalg.norm(n) < 1e-9:
            raise ValueError("normal_axis must be non-zero: the pad's press direction in the link frame")
        n = n / np.linalg.norm(n)
        u = u - (u @ n) * n
        if np.linalg.norm(u) < 1e-6:
            raise ValueError("up_axis must not be parallel to normal_axis")
        self.body, self.link, self.client, self.name = int(body), int(link), int(client), name
        self.pad_center = None if pad_center is None else np.asarray(pad_center, dtype=np.float64)
        if self.pad_center is not None and self.pad_center.shape != (3,):
            raise ValueError(f"pad_center must be (3,) in the link frame, got {self.pad_center.shape}")
        self.normal_axis, self.up_axis = n, u / np.linalg.norm(u)
        self.pad = pad or PadConfig()
        self.sim = simulator if simulator is not None else LazySimulator(self.pad)
        self.objects: dict[int, trimesh.Trimesh] = {}
        self._cache: dict | None = None
        self.num_presses = 0

    # ------------------------------------------------------------------ registry
    def attach_object(self, body: int, mesh: trimesh.Trimesh) -> None:
        """Register a body the pad can feel; ``mesh`` is its surface in that body's base (COM) frame, metres."""
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError("attach_object needs a non-empty trimesh.Trimesh in the body's base frame")
        self.objects[int(body)] = mesh

    def reset(self) -> None:
        """Forget the cached press: the pad is at rest."""
        self._cache = None

    # ------------------------------------------------------------------ geometry
    def link_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) world position, (3,3) world rotation) float64 of the finger link frame."""
        if self.link < 0:
            pos, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        else:
            st = p.getLinkState(self.body, self.link, computeForwardKinematics=True, physicsClientId=self.client)
            pos, orn = st[4], st[5]
        return np.asarray(pos, dtype=np.float64), np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)

    def world_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) press direction, (3,) up axis) of the pad in world coordinates."""
        _, R = self.link_pose()
        return R @ self.normal_axis, R @ self.up_axis

    def _body_pose(self, body: int) -> np.ndarray:
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        T = np.eye(4)
        T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
        T[:3, 3] = pos
        return T

    def contacts(self) -> list[tuple]:
        """pybullet contact points between this link and registered objects (touching: distance <= 0)."""
        out = []
        for body in self.objects:
            pts = p.getContactPoints(bodyA=self.body, bodyB=body, linkIndexA=self.link, physicsClientId=self.client)
            out.extend(c for c in pts if c[8] <= 1e-5)
        return out

    # ------------------------------------------------------------------ sensing
    def sense(self, refresh: bool = False) -> FingerReading:
        """Read the pad at the current simulation step.

        Args:
            refresh: force a new EIP press if in contact (e.g. at the start of a control phase).

        Returns:
            A :class:`FingerReading` (image (3,H,W) float32 in the pad frame; zeros and contact False at rest).
        """
        return sense_fingers([self], refresh=refresh)[0]

    def _measure(self, refresh: bool) -> tuple[FingerReading, dict | None]:
        """Contact geometry from pybullet; returns the reading (image from the cache) and the press to run, if any."""
        H, W = self.pad.resolution
        d_world, up_world = self.world_axes()
        pts = self.contacts()
        force = float(sum(c[9] for c in pts))
        if not pts or force < self.pad.min_force:
            self._cache = None  # the pad is back at rest
            rest = np.zeros((3, H, W), np.float32)
            return FingerReading(
                rest, False, force, np.zeros(3), np.full(3, np.nan), d_world, 0.0, 0.0, -1, False
            ), None
        per_body: dict[int, float] = {}
        for c in pts:
            per_body[c[2]] = per_body.get(c[2], 0.0) + c[9]
        body = max(per_body, key=per_body.get)
        pts = [c for c in pts if c[2] == body]
        w = np.array([max(c[9], 1e-9) for c in pts])
        pos_b = np.array([c[6] for c in pts])  # (N,3) points on the object
        normals = np.array([c[7] for c in pts])  # contact normal on B (object -> finger)
        position = (w[:, None] * pos_b).sum(0) / w.sum()
        if self.pad_center is not None:  # the contact plane's point in front of the pad centre
            link_pos, R = self.link_pose()
            centre = link_pos + R @ self.pad_center
            position = centre + d_world * float((position - centre) @ d_world)
        force_vec = (w[:, None] * normals).sum(0)  # object pushes the finger along +normalOnB
        penetration = float(max(0.0, -min(c[8] for c in pts)))
        # the pad's indentation: its elastic give under the measured force, at least the geometric overlap,
        # rounded to 0.05 mm so that presses of equal depth can share one batched solver call
        depth = float(np.clip(max(penetration, force / self.pad.stiffness), self.pad.min_depth, self.pad.max_depth))
        depth = round(depth / 5e-5) * 5e-5
        T = self._body_pose(body)
        local = (np.linalg.inv(T) @ np.append(position, 1.0))[:3]
        c = self._cache
        need = (
            refresh
            or c is None
            or c["body"] != body
            or np.linalg.norm(local - c["local"]) > self.pad.move_tol
            or abs(depth - c["depth"]) > self.pad.depth_tol * c["depth"]
        )
        image = None if need else c["image"]
        reading = FingerReading(image, True, force, force_vec, position, d_world, penetration, depth, body, need)
        job = None
        if need:
            mesh = self.objects[body].copy().apply_transform(T)
            job = {
                "mesh": mesh,
                "position": position,
                "direction": d_world,
                "up": up_world,
                "depth": depth,
                "body": body,
                "local": local,
            }
        return reading, job

    def _store(self, reading: FingerReading, job: dict, image: np.ndarray) -> None:
        self._cache = {"body": job["body"], "local": job["local"], "depth": job["depth"], "image": image}
        reading.image = image
        self.num_presses += 1


def sense_fingers(fingers: Sequence[TactileFinger], refresh: bool = False) -> list[FingerReading]:
    """Read several fingers at the current step, running the needed EIP presses as batched solver calls.

    Fingers sharing one simulator whose presses have the same depth go through one ``press_batch`` call (one grid
    block per touch), so a two-finger grasp costs one solver loop instead of two.

    Args:
        fingers: the fingers to read.
        refresh: force new presses for every finger in contact (e.g. at the start of a control phase).

    Returns:
        One :class:`FingerReading` per finger, in order.
    """
    measured = [f._measure(refresh) for f in fingers]
    groups: dict[tuple[int, float], list[int]] = {}
    for i, (_, job) in enumerate(measured):
        if job is not None:
            groups.setdefault((id(fingers[i].sim), job["depth"]), []).append(i)
    for (_, depth), idx in groups.items():
        sim = fingers[idx[0]].sim
        pad = fingers[idx[0]].pad
        jobs = [measured[i][1] for i in idx]
        readings = sim.press_batch(
            [j["mesh"] for j in jobs],
            torch.as_tensor(np.stack([j["position"] for j in jobs]), dtype=torch.float32),
            torch.as_tensor(np.stack([j["direction"] for j in jobs]), dtype=torch.float32),
            depth=depth / pad.dx,
            threshold=None,
        )
        for i, job, r in zip(idx, jobs, readings):
            f = fingers[i]
            if r.contact:
                img = to_pad_frame(r.image.detach().float().cpu(), job["direction"], job["up"]).numpy()
            else:
                img = np.zeros((3, *f.pad.resolution), np.float32)
            f._store(measured[i][0], job, img.astype(np.float32))
    return [m[0] for m in measured]
