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

__all__ = ["PadConfig", "FingerReading", "TactileFinger", "to_pad_frame"]


@dataclass
class PadConfig:
    """Physical pad and press settings of a :class:`TactileFinger`.

    resolution: (H, W) tactile pixels; pad_size: physical width of the contact layer in metres (2 cm default).
    n_grid: MPM grid cells across the press domain (the domain spans ``n_grid * dx`` metres, dx = pad cell size).
    stiffness: N/m of the pad's elastic give (indentation = penetration + force / stiffness).
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
    stiffness: float = 2.0e4
    min_depth: float = 2.0e-4
    max_depth: float = 2.0e-3
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
        self.normal_axis, self.up_axis = n, u / np.linalg.norm(u)
        self.pad = pad or PadConfig()
        self._sim = simulator  # built lazily from ``pad`` on the first press
        self.objects: dict[int, trimesh.Trimesh] = {}
        self._cache: dict | None = None
        self.num_presses = 0

    @property
    def sim(self) -> object:
        """The EIP simulator used for presses (``tvrecon.sim.press.EIPSimulator``), built on first use."""
        if self._sim is None:
            self._sim = self._build_simulator()
        return self._sim

    @sim.setter
    def sim(self, value: object) -> None:
        self._sim = value

    def _build_simulator(self) -> object:
        from tvrecon.sim.press import EIPSimulator, PressConfig
        from tvrecon.sim.sensor import SensorConfig

        pc = self.pad
        sensor = SensorConfig(resolution=tuple(pc.resolution), layers=pc.layers, spacing=0.5, E=pc.E, nu=pc.nu)
        press = PressConfig(n_grid=pc.n_grid, domain_size=pc.domain_size, max_steps=pc.max_steps)
        return EIPSimulator(sensor=sensor, press=press)

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
    def link_rotation(self) -> np.ndarray:
        """(3,3) float64 world rotation of the finger link frame."""
        if self.link < 0:
            _, orn = p.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        else:
            orn = p.getLinkState(self.body, self.link, computeForwardKinematics=True, physicsClientId=self.client)[5]
        return np.asarray(p.getMatrixFromQuaternion(orn)).reshape(3, 3)

    def world_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) press direction, (3,) up axis) of the pad in world coordinates."""
        R = self.link_rotation()
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
        H, W = self.pad.resolution
        d_world, up_world = self.world_axes()
        pts = self.contacts()
        force = float(sum(c[9] for c in pts))
        if not pts or force < self.pad.min_force:
            self._cache = None
            return FingerReading(
                np.zeros((3, H, W), np.float32),
                False,
                force,
                np.zeros(3),
                np.full(3, np.nan),
                d_world,
                0.0,
                0.0,
                -1,
                False,
            )
        per_body: dict[int, float] = {}
        for c in pts:
            per_body[c[2]] = per_body.get(c[2], 0.0) + c[9]
        body = max(per_body, key=per_body.get)
        pts = [c for c in pts if c[2] == body]
        w = np.array([max(c[9], 1e-9) for c in pts])
        pos_b = np.array([c[6] for c in pts])  # (N,3) points on the object
        normals = np.array([c[7] for c in pts])  # contact normal on B (object -> finger)
        position = (w[:, None] * pos_b).sum(0) / w.sum()
        force_vec = (w[:, None] * normals).sum(0)  # object pushes the finger along +normalOnB
        penetration = float(max(0.0, -min(c[8] for c in pts)))
        depth = float(np.clip(penetration + force / self.pad.stiffness, self.pad.min_depth, self.pad.max_depth))
        T = self._body_pose(body)
        local = np.linalg.inv(T) @ np.append(position, 1.0)
        c = self._cache
        need = (
            refresh
            or c is None
            or c["body"] != body
            or np.linalg.norm(local[:3] - c["local"]) > self.pad.move_tol
            or abs(depth - c["depth"]) > self.pad.depth_tol * c["depth"]
        )
        if need:
            image = self._press(body, T, position, d_world, up_world, depth)
            self._cache = {"body": body, "local": local[:3], "depth": depth, "image": image}
        return FingerReading(
            self._cache["image"], True, force, force_vec, position, d_world, penetration, depth, body, bool(need)
        )

    def _press(
        self, body: int, T: np.ndarray, position: np.ndarray, direction: np.ndarray, up: np.ndarray, depth: float
    ) -> np.ndarray:
        mesh_world = self.objects[body].copy().apply_transform(T)
        reading = self.sim.press(
            mesh_world,
            torch.as_tensor(position, dtype=torch.float32),
            torch.as_tensor(direction, dtype=torch.float32),
            depth=depth / self.pad.dx,
            threshold=None,
        )
        self.num_presses += 1
        if not reading.contact:
            return np.zeros((3, *self.pad.resolution), np.float32)
        img = to_pad_frame(reading.image.detach().float().cpu(), direction, up)
        return img.numpy().astype(np.float32)
