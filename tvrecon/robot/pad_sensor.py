"""The EIP pad on a robot link, independent of the physics engine: config, reading, caching, batched presses.

A :class:`PadSensor` turns the engine's contacts of one link (or geom) into EIP presses of the touched object's own
mesh: the press is centred on the pad (or the force-weighted contact point), goes along the pad's normal (fixed in
the link frame) and indents by the engine's penetration or the pad's elastic give under the measured force. The
tactile image is returned in the pad's frame (rows along the link's ``up_axis``, columns ``up x normal``).

The engine side is three methods: :meth:`PadSensor.link_pose`, :meth:`PadSensor.contact_points` (as
:class:`ContactPoint`) and :meth:`PadSensor.object_transform` (+ the object meshes in :attr:`PadSensor.objects`).
``tvrecon.robot.pybullet.finger.TactileFinger`` implements them for pybullet,
``tvrecon.robot.mujoco.sensor.TactileSensor`` for MuJoCo; everything else (which presses to run, their caching, one
batched solver call for all pads of a step, the pad-frame image, force field and world contact patch) lives here
once.

Presses are cached: the pad is re-simulated only when the contact starts, moves on the object, changes depth by a
set fraction, or the caller asks (e.g. once per control phase). Without contact the pad is at rest: zero image,
``contact=False``, no simulation.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
import trimesh

from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pad_reading import ContactPoint, FingerReading
from tvrecon.utils.shape_check import check_shape

__all__ = ["LazySimulator", "PadSensor", "sense_pads", "to_pad_frame"]


class LazySimulator:
    """An EIP simulator for a :class:`PadConfig`, built on the first press (so a scene without contact never loads
    the solver). Share one instance between pads so their presses can be batched."""

    def __init__(self, pad: PadConfig) -> None:
        self.pad = pad
        self._sim = None

    @property
    def sim(self) -> object:
        """The ``tvrecon.sim.press.simulator.EIPSimulator`` (pad resolution and spacing, domain sized from the pad)."""
        if self._sim is None:
            from tvrecon.sim.press.config import PressConfig
            from tvrecon.sim.press.simulator import EIPSimulator
            from tvrecon.sim.sensor.elastic_pad import SensorConfig

            pc = self.pad
            sensor = SensorConfig(
                resolution=tuple(pc.resolution), layers=pc.layers, spacing=pc.spacing, E=pc.E, nu=pc.nu
            )
            press = PressConfig(
                n_grid=pc.n_grid, domain_size=pc.domain_size, max_steps=pc.max_steps, speed_fraction=pc.speed_fraction
            )
            self._sim = EIPSimulator(sensor=sensor, press=press)
        return self._sim

    @property
    def sensor(self) -> object:
        """The simulator's ``SensorConfig``."""
        return self.sim.sensor

    @property
    def cfg(self) -> object:
        """The simulator's ``PressConfig``."""
        return self.sim.cfg

    def press(self, mesh: trimesh.Trimesh, position: object, direction: object, **overrides: object) -> object:
        """``EIPSimulator.press``."""
        return self.sim.press(mesh, position, direction, **overrides)

    def press_batch(self, meshes: object, positions: object, directions: object, **overrides: object) -> list:
        """``EIPSimulator.press_batch``."""
        return self.sim.press_batch(meshes, positions, directions, **overrides)


def to_pad_frame(image: torch.Tensor, direction: np.ndarray, up: np.ndarray) -> torch.Tensor:
    """Resample a simulator tactile image from the simulator's sensor frame into a finger pad frame.

    The simulator frame (``tvrecon.sim.sensor.elastic_pad.sensor_frame``) has e_z = -direction and e_x from the world x
    axis; the pad frame shares e_z and has e_y along ``up`` (projected onto the contact plane), e_x = e_y x e_z. Pixels
    are bilinearly resampled (zeros outside the pad) and the shear channels rotated with the frame.

    Args:
        image: (3,H,W) float32 tactile image in the simulator's sensor frame.
        direction: (3,) press direction in world coordinates.
        up: (3,) the pad's "up" axis in world coordinates (not parallel to ``direction``).

    Returns:
        (3,H,W) float32 image in the pad frame.
    """
    from tvrecon.sim.sensor.elastic_pad import sensor_frame

    check_shape(image, "(3, H, W)", "image")
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


class PadSensor:
    """An EIP pad on an engine link; subclasses supply the engine side (see the module docstring).

    Args:
        normal_axis: (3,) pad press direction in the link frame (the finger's closing direction).
        up_axis: (3,) pad "up" axis in the link frame (image rows), e.g. along the finger towards its tip.
        pad_center: (3,) centre of the pad's contact face in the link frame; the press is then centred on the pad
            (the contact plane point in front of it), so the image shows where on the pad the object touches.
            None centres the press on the force-weighted contact point instead.
        pad: pad geometry and caching thresholds.
        simulator: a ``tvrecon.sim.press.simulator.EIPSimulator`` or :class:`LazySimulator`; None builds one from
        ``pad``. name: label used in logs.
        use_penetration: the press depth is max(engine penetration, force / stiffness) when True, force / stiffness
            alone when False (for engines whose penetration is a soft-constraint setting, not a geometric overlap).
    """

    def __init__(
        self,
        normal_axis: Sequence[float],
        up_axis: Sequence[float] = (0.0, 0.0, 1.0),
        pad_center: Sequence[float] | None = None,
        pad: PadConfig | None = None,
        simulator: object | None = None,
        name: str = "finger",
        use_penetration: bool = True,
    ) -> None:
        n = np.asarray(normal_axis, dtype=np.float64)
        u = np.asarray(up_axis, dtype=np.float64)
        check_shape(n, "(3,)", "normal_axis")
        check_shape(u, "(3,)", "up_axis")
        if np.linalg.norm(n) < 1e-9:
            raise ValueError("normal_axis must be non-zero: the pad's press direction in the link frame")
        n = n / np.linalg.norm(n)
        u = u - (u @ n) * n
        if np.linalg.norm(u) < 1e-6:
            raise ValueError("up_axis must not be parallel to normal_axis")
        self.name = name
        self.use_penetration = bool(use_penetration)
        self.pad_center = None if pad_center is None else np.asarray(pad_center, dtype=np.float64)
        if self.pad_center is not None:
            check_shape(self.pad_center, "(3,)", "pad_center")
        self.normal_axis, self.up_axis = n, u / np.linalg.norm(u)
        self.pad = pad or PadConfig()
        self.sim = simulator if simulator is not None else LazySimulator(self.pad)
        self.objects: dict[int, trimesh.Trimesh] = {}
        self._cache: dict | None = None
        self.num_presses = 0

    # ------------------------------------------------------------------ engine side
    def link_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) world position, (3,3) world rotation) float64 of the pad's link frame."""
        raise NotImplementedError

    def contact_points(self) -> list[ContactPoint]:
        """The link's current contacts with the objects the pad can feel."""
        raise NotImplementedError

    def object_transform(self, key: int) -> np.ndarray:
        """(4,4) float64 world transform of object ``key``'s mesh frame (``objects[key]`` is in that frame)."""
        raise NotImplementedError

    def object_mesh(self, key: int) -> trimesh.Trimesh:
        """Object ``key``'s surface in its own frame (metres)."""
        return self.objects[key]

    # ------------------------------------------------------------------ shared
    def attach_object(self, key: int, mesh: trimesh.Trimesh) -> None:
        """Register an object the pad can feel; ``mesh`` is its surface in the object's frame, metres."""
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError("attach_object needs a non-empty trimesh.Trimesh in the body's base frame")
        self.objects[int(key)] = mesh

    def reset(self) -> None:
        """Forget the cached press: the pad is at rest."""
        self._cache = None

    def world_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) press direction, (3,) up axis) of the pad in world coordinates."""
        _, R = self.link_pose()
        return R @ self.normal_axis, R @ self.up_axis

    def sense(self, refresh: bool = False) -> FingerReading:
        """Read the pad at the current simulation step.

        Args:
            refresh: force a new EIP press if in contact (e.g. at the start of a control phase).

        Returns:
            A :class:`FingerReading` (image (3,H,W) float32 in the pad frame; zeros and contact False at rest).
        """
        return sense_pads([self], refresh=refresh)[0]

    def rest_reading(self, force: float = 0.0) -> FingerReading:
        """The pad at rest (no simulation): zero image and force field, no patch."""
        H, W = self.pad.resolution
        d_world, _ = self.world_axes()
        zeros = np.zeros((3, H, W), np.float32)
        return FingerReading(
            zeros,
            False,
            float(force),
            np.zeros(3),
            np.full(3, np.nan),
            d_world,
            0.0,
            0.0,
            -1,
            False,
            force_field=zeros.copy(),
            patch=np.zeros((0, 3)),
            spacing=self.pad.spacing,
        )

    def _measure(self, refresh: bool) -> tuple[FingerReading, dict | None]:
        """Contact geometry from the engine; returns the reading (from the cache) and the press to run, if any."""
        pts = self.contact_points()
        force = float(sum(c.force for c in pts))
        if not pts or force < self.pad.min_force:
            self._cache = None  # the pad is back at rest
            return self.rest_reading(force), None
        link_pos, R = self.link_pose()
        d_world, up_world = R @ self.normal_axis, R @ self.up_axis
        per_key: dict[int, float] = {}
        for c in pts:
            per_key[c.key] = per_key.get(c.key, 0.0) + c.force
        key = max(per_key, key=per_key.get)
        pts = [c for c in pts if c.key == key]
        w = np.array([max(c.force, 1e-9) for c in pts])
        pos_b = np.array([c.position for c in pts])  # (N,3) points on the object
        normals = np.array([c.normal for c in pts])  # (N,3) contact normals, object -> finger
        position = (w[:, None] * pos_b).sum(0) / w.sum()
        if self.pad_center is not None:  # the contact plane's point in front of the pad centre
            centre = link_pos + R @ self.pad_center
            position = centre + d_world * float((position - centre) @ d_world)
        force_vec = (w[:, None] * normals).sum(0)  # the object pushes the finger along the normals
        penetration = float(max(0.0, max(c.penetration for c in pts)))
        # the pad's indentation: its elastic give under the measured force, at least the geometric overlap (when
        # the engine's penetration is one), rounded to 0.05 mm so that presses of equal depth share one solver call
        give = force / self.pad.stiffness
        depth = max(penetration, give) if self.use_penetration else give
        depth = float(np.clip(depth, self.pad.min_depth, self.pad.max_depth))
        depth = round(depth / 5e-5) * 5e-5
        T = self.object_transform(key)
        local = (np.linalg.inv(T) @ np.append(position, 1.0))[:3]
        c = self._cache
        need = (
            refresh
            or c is None
            or c["body"] != key
            or np.linalg.norm(local - c["local"]) > self.pad.move_tol
            or abs(depth - c["depth"]) > self.pad.depth_tol * c["depth"]
        )
        reading = FingerReading(
            None if need else c["image"],
            True,
            force,
            force_vec,
            position,
            d_world,
            penetration,
            depth,
            key,
            need,
            force_field=None if need else c["force_field"],
            patch=None if need else link_pos + c["patch_link"] @ R.T,
            spacing=self.pad.spacing,
        )
        job = None
        if need:
            job = {
                "mesh": self.object_mesh(key).copy().apply_transform(T),
                "position": position,
                "direction": d_world,
                "up": up_world,
                "depth": depth,
                "body": key,
                "local": local,
                "link": (link_pos, R),
            }
        return reading, job

    def _store(self, reading: FingerReading, job: dict, image: np.ndarray, ff: np.ndarray, patch: np.ndarray) -> None:
        link_pos, R = job["link"]
        self._cache = {
            "body": job["body"],
            "local": job["local"],
            "depth": job["depth"],
            "image": image,
            "force_field": ff,
            "patch_link": (patch - link_pos) @ R,  # (M,3) in the link frame: the patch moves with the pad
        }
        reading.image, reading.force_field, reading.patch = image, ff, patch
        self.num_presses += 1


def _simulator_configs(sim: object) -> tuple[object, object]:
    inner = getattr(sim, "sim", sim)  # LazySimulator -> EIPSimulator
    return inner.sensor, inner.cfg


def sense_pads(pads: Sequence[PadSensor], refresh: bool = False) -> list[FingerReading]:
    """Read several pads at the current step, running the needed EIP presses as batched solver calls.

    Pads sharing one simulator whose presses have the same depth go through one ``press_batch`` call (one grid
    block per touch), so a two-finger grasp costs one solver loop instead of two. Pads without contact cost no
    simulation.

    Args:
        pads: the pads to read (pybullet ``TactileFinger``, MuJoCo ``TactileSensor``, any :class:`PadSensor`).
        refresh: force new presses for every pad in contact (e.g. at the start of a control phase).

    Returns:
        One :class:`FingerReading` per pad, in order.
    """
    from tvrecon.sim.sensor.patch import contact_patch

    measured = [f._measure(refresh) for f in pads]
    groups: dict[tuple[int, float], list[int]] = {}
    for i, (_, job) in enumerate(measured):
        if job is not None:
            groups.setdefault((id(pads[i].sim), job["depth"]), []).append(i)
    for (_, depth), idx in groups.items():
        sim = pads[idx[0]].sim
        pad = pads[idx[0]].pad
        jobs = [measured[i][1] for i in idx]
        readings = sim.press_batch(
            [j["mesh"] for j in jobs],
            torch.as_tensor(np.stack([j["position"] for j in jobs]), dtype=torch.float32),
            torch.as_tensor(np.stack([j["direction"] for j in jobs]), dtype=torch.float32),
            depth=depth / pad.dx,
            threshold=None,
        )
        sensor, press = _simulator_configs(sim)
        for i, job, r in zip(idx, jobs, readings):
            f = pads[i]
            H, W = f.pad.resolution
            img = np.zeros((3, H, W), np.float32)
            ff = np.zeros((3, H, W), np.float32)
            patch = np.zeros((0, 3))
            if r.contact:
                sim_img = r.image.detach().float().cpu()
                img = to_pad_frame(sim_img, job["direction"], job["up"]).numpy()
                if r.force_field is not None:
                    field_img = r.force_field.detach().float().cpu().permute(2, 0, 1)  # (3,H,W)
                    ff = to_pad_frame(field_img, job["direction"], job["up"]).numpy()
                cp = contact_patch(
                    sim_img, r.position.cpu(), r.direction.cpu(), sensor, press.n_grid, press.domain_size
                )
                patch = cp.points[cp.mask].double().numpy()
            f._store(measured[i][0], job, img.astype(np.float32), ff.astype(np.float32), patch)
    return [m[0] for m in measured]
