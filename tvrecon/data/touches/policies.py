"""Touch policies: where, in which direction and how hard the sensor presses.

A touch is a contact point on the surface, a press direction into the object and a press strength (the simulator's
stop rule: a terminal-chamfer (paper eq. 12) ``threshold``, an indentation ``depth`` or a ``force``). A
:class:`TouchPolicy` samples them: ``policy.sample(mesh, n, rng, camera=, sim=)`` returns :class:`Touches`. The
default, :class:`ConeTouchPolicy`, draws area-weighted points (optionally only where the camera sees the object),
directions in a cone around the inward normal and strengths from a configured list: the paper's "different press
directions and forces". Data configs pick a policy with ``touch._target_`` (:func:`make_touch_policy`).

`sample_touches` seeds a policy, `simulate_touches` runs the touches through `EIPSimulator.press_batch`,
`resize_tactile` brings raw tactile images to the model resolution with kornia.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

import kornia
import numpy as np
import torch
import trimesh
from torch import Tensor
from tqdm.auto import tqdm

from tvrecon.data.views import Camera, ray_intersector
from tvrecon.sim.press.placement import pad_footprint, pad_reachable
from tvrecon.utils.config_utils import coerce_config, omitted_from_key
from tvrecon.utils.geometry import check_mesh, perpendicular_basis, world_to_camera
from tvrecon.utils.shape_check import check_shape

if TYPE_CHECKING:  # the simulator is only needed by the caller of simulate_touches
    from tvrecon.sim.press.reading import TactileReading
    from tvrecon.sim.press.simulator import EIPSimulator

__all__ = [
    "ConeTouchPolicy",
    "TouchPolicy",
    "Touches",
    "make_touch_policy",
    "cone_directions",
    "resize_tactile",
    "sample_touches",
    "simulate_touches",
    "visible_points",
]


def _default_strengths() -> tuple[dict, ...]:
    # terminal-chamfer thresholds (paper eq. 12; squared grid cells per contact-layer particle) around the
    # simulator's default
    return ({"threshold": 0.025}, {"threshold": 0.05}, {"threshold": 0.1})


class Touches(NamedTuple):
    """T sampled touches, what every :class:`TouchPolicy` returns.

    Attributes:
        positions: (T, 3) float32 world points on the surface.
        directions: (T, 3) float32 unit press directions (into the object).
        normals: (T, 3) float32 outward surface normals at the positions.
        strengths: T dicts of `EIPSimulator.press` overrides (the stop rule of each press).
    """

    positions: Tensor
    directions: Tensor
    normals: Tensor
    strengths: list[dict]

    def take(self, t: int) -> Touches:
        """Touch ``t`` alone, as a batch of one ((1, 3) tensors, one strength)."""
        if not -len(self.strengths) <= t < len(self.strengths):
            raise IndexError(f"touch {t} of {len(self.strengths)}")
        t = t % len(self.strengths)
        return Touches(
            self.positions[t : t + 1], self.directions[t : t + 1], self.normals[t : t + 1], [self.strengths[t]]
        )


class TouchPolicy:
    """Where, in which direction and how hard to press: the interface of the touch policies.

    A policy is a dataclass (its fields are its configuration) with :meth:`sample`. The data configs select one with
    ``touch._target_`` (``configs/data/touch/*.yaml``); :func:`make_touch_policy` builds it. Its fields go into the
    cache key of every sample (:meth:`cache_spec`).

    Attributes:
        key_target: the class path a sample's cache key names (:meth:`cache_spec`): the path the class had when its
            samples were first cached, so a move of its module keeps them; None: its current path.
    """

    key_target: ClassVar[str | None] = None

    def sample(
        self,
        mesh: trimesh.Trimesh,
        n: int,
        rng: np.random.Generator,
        camera: Camera | None = None,
        sim: EIPSimulator | None = None,
    ) -> Touches:
        """Sample ``n`` touches on ``mesh`` (see :func:`sample_touches` for the arguments)."""
        raise NotImplementedError

    def cache_spec(self) -> dict[str, Any]:
        """What of the policy goes into a sample's cache key: its class and its fields.

        The default policy (:class:`ConeTouchPolicy`, exactly that class) gives its fields only, the key every sample
        had before policies were pluggable, so existing caches stay valid; any other policy adds its ``_target_``.
        """
        fields = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)  # type: ignore[arg-type]
            if not omitted_from_key(f, getattr(self, f.name))  # a field added later, at its default: old keys hold
        }
        if type(self) is ConeTouchPolicy:
            return fields
        target = self.key_target or f"{type(self).__module__}.{type(self).__qualname__}"
        return {"_target_": target, **fields}


@dataclass
class ConeTouchPolicy(TouchPolicy):
    """The default policy: area-weighted surface points, press directions in a cone around the inward normal.

    Contact points are drawn uniformly by area (optionally only where the camera sees the object, and only where
    the simulator's pad can approach), each press direction uniformly by solid angle inside a cone around the
    inward normal -n, and each strength uniformly from ``strengths``: the paper's "different press directions and
    forces".

    Attributes:
        cone_deg: half-angle (degrees) of the cone around the inward normal -n in which press directions are
            drawn uniformly (0 = exactly along -n).
        strengths: press strengths, each a dict of `EIPSimulator.press` overrides (e.g. {"threshold": 0.05},
            {"depth": 3.0} cells, {"force": 2.0}); every touch draws one uniformly.
        visible_only: keep only contact points the camera sees (needs `camera=` in `sample_touches`).
        oversample: candidates drawn per wanted touch before the visibility test.
    """

    cone_deg: float = 15.0
    strengths: Sequence[Mapping] = field(default_factory=_default_strengths)
    visible_only: bool = False
    oversample: int = 8

    def __post_init__(self) -> None:
        what = type(self).__name__
        self.cone_deg = float(self.cone_deg)  # `cone_deg=15` and `cone_deg=15.0`: one policy, one cache key
        self.visible_only = bool(self.visible_only)
        self.oversample = int(self.oversample)
        if not 0.0 <= self.cone_deg < 90.0:
            raise ValueError(f"{what}.cone_deg must be in [0, 90) degrees, got {self.cone_deg}")
        if isinstance(self.strengths, Mapping) or len(self.strengths) == 0:
            raise ValueError(
                f"{what}.strengths must be a non-empty list of dicts like [{{'threshold': 0.05}}], "
                f"got {self.strengths!r}"
            )
        strengths = []
        for s in self.strengths:
            if not isinstance(s, Mapping):
                raise ValueError(f"each {what}.strengths entry must be a dict of press overrides, got {s!r}")
            strengths.append({str(k): v for k, v in s.items()})
        self.strengths = tuple(strengths)
        if self.oversample < 1:
            raise ValueError(f"{what}.oversample must be >= 1, got {self.oversample}")

    def sample(self, mesh, n, rng, camera=None, sim=None) -> Touches:  # the arguments of TouchPolicy.sample
        points, normals, directions = self._candidates(mesh, n, n, rng, camera, sim)
        return self._touches(points[:n], normals[:n], directions[:n], rng)

    def _candidates(
        self,
        mesh: trimesh.Trimesh,
        n: int,
        count: int,
        rng: np.random.Generator,
        camera: Camera | None,
        sim: EIPSimulator | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At least ``n`` candidate (points, outward normals, directions) passing the filters, in draw order.

        ``count`` candidates are drawn when nothing is filtered (``n * oversample`` when something is), four times
        more on each retry when too few pass.
        """
        if self.visible_only and not isinstance(camera, Camera):
            raise ValueError(f"{type(self).__name__}.visible_only needs the view: pass camera=Camera(...)")
        filtered = self.visible_only or sim is not None
        footprint = pad_footprint(sim.sensor, sim.cfg) if sim is not None else None
        kept: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        count = n * self.oversample if filtered else count
        for _ in range(4):  # grow the candidate pool when few candidates pass the filters
            pts, faces = trimesh.sample.sample_surface(mesh, count, seed=rng)
            normals = mesh.face_normals[faces]  # (C, 3) outward
            dirs = cone_directions(-normals, self.cone_deg, rng)
            keep = np.ones(len(pts), dtype=bool)
            if self.visible_only:
                keep &= visible_points(mesh, pts, normals, camera)
            if footprint is not None:
                idx = np.flatnonzero(keep)
                keep[idx] = pad_reachable(mesh, pts[idx], dirs[idx], *footprint)
            kept.append((pts[keep], normals[keep], dirs[keep]))
            if sum(len(k[0]) for k in kept) >= n:
                break
            count *= 4
        points, normals, directions = (np.concatenate([k[i] for k in kept]) for i in range(3))
        if len(points) < n:
            what = " and ".join(
                w for w, on in (("visible from the camera", self.visible_only), ("reachable by the pad", sim)) if on
            )
            raise ValueError(
                f"only {len(points)} of {n} touch points are {what}: is the camera inside the object or looking "
                "away, or is the pad too large for this object? Use visible_only=False, another camera or a "
                "smaller pad"
            )
        return points, normals, directions

    def _touches(
        self, points: np.ndarray, normals: np.ndarray, directions: np.ndarray, rng: np.random.Generator
    ) -> Touches:
        """The chosen candidates as :class:`Touches`, each with a strength drawn from ``strengths``."""
        which = rng.integers(len(self.strengths), size=len(points))
        return Touches(
            positions=torch.as_tensor(points, dtype=torch.float32),
            directions=torch.as_tensor(directions, dtype=torch.float32),
            normals=torch.as_tensor(normals, dtype=torch.float32),
            strengths=[dict(self.strengths[i]) for i in which],
        )


def make_touch_policy(value: TouchPolicy | Mapping[str, Any] | None) -> TouchPolicy:
    """The policy of a data config's ``touch`` entry: a policy (kept), ``None`` (the default
    :class:`ConeTouchPolicy`), or a mapping of its fields with an optional ``_target_`` naming its class
    (default :class:`ConeTouchPolicy`); unknown fields raise ValueError listing the valid ones."""
    if isinstance(value, TouchPolicy):
        return value
    if value is None:
        return ConeTouchPolicy()
    value = _plain(value)
    if not isinstance(value, Mapping):
        raise ValueError(f"touch must be a TouchPolicy or a mapping of its fields, got {type(value).__name__}")
    fields = dict(value)
    target = fields.pop("_target_", None)
    cls = ConeTouchPolicy if target is None else _policy_class(str(target))
    return coerce_config(cls, fields, f"touch ({cls.__name__})")


def _plain(value: Any) -> Any:
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(value, DictConfig):
            return OmegaConf.to_container(value, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a hard dependency
        pass
    return value


def _policy_class(target: str) -> type[TouchPolicy]:
    module, _, name = target.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError, ValueError) as err:
        raise ValueError(f"touch._target_ {target!r} names no importable class ({err})") from None
    if not (isinstance(cls, type) and issubclass(cls, TouchPolicy) and dataclasses.is_dataclass(cls)):
        raise ValueError(f"touch._target_ {target!r} is not a TouchPolicy dataclass")
    return cls


def cone_directions(axes: np.ndarray, half_angle_deg: float, rng: np.random.Generator) -> np.ndarray:
    """Unit directions drawn uniformly (by solid angle) in cones around `axes`.

    Args:
        axes: (T, 3) cone axes (any non-zero length).
        half_angle_deg: cone half-angle in degrees, in [0, 90).
        rng: numpy random generator.

    Returns:
        (T, 3) float64 unit vectors d with angle(d, axis) <= half_angle_deg.
    """
    axes = np.asarray(axes, dtype=np.float64)
    check_shape(axes, "(T, 3)", "axes")
    a = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    cos_max = np.cos(np.deg2rad(half_angle_deg))
    cos_t = 1.0 - rng.uniform(size=len(a)) * (1.0 - cos_max)  # uniform on the spherical cap
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    phi = rng.uniform(0.0, 2 * np.pi, size=len(a))
    e1, e2 = perpendicular_basis(a)
    d = cos_t[:, None] * a + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def visible_points(mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray, camera: Camera) -> np.ndarray:
    """Which surface points the camera sees: in front of it, inside the image, facing it and not occluded.

    Args:
        mesh: the object, world coordinates.
        points: (N, 3) points on the surface. normals: (N, 3) their outward normals.
        camera: the view.

    Returns:
        (N,) bool.
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    check_shape(points, "(N, 3)", "points")
    if normals.shape != points.shape:
        raise ValueError(f"normals must have the shape of points {points.shape}, got {normals.shape}")
    center = camera.center.double().numpy()
    cam = world_to_camera(torch.from_numpy(points), camera.RT.double()).numpy()  # (N, 3)
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = cam[:, :2] / z[:, None] @ camera.K.double().numpy()[:2, :2].T + camera.K.double().numpy()[:2, 2]
    in_frame = (z > 0) & (uv[:, 0] > -0.5) & (uv[:, 0] < camera.width - 0.5)
    in_frame &= (uv[:, 1] > -0.5) & (uv[:, 1] < camera.height - 0.5)
    to_cam = center - points
    dist = np.linalg.norm(to_cam, axis=1)
    facing = np.einsum("ij,ij->i", normals, to_cam) > 0
    visible = np.zeros(len(points), dtype=bool)
    test = np.flatnonzero(in_frame & facing)
    if len(test) == 0:
        return visible
    dirs = -to_cam[test] / dist[test, None]
    _, ray, loc = ray_intersector(mesh).intersects_id(
        np.broadcast_to(center, dirs.shape).copy(), dirs, multiple_hits=False, return_locations=True
    )
    tol = 1e-3 * max(float(mesh.scale), 1e-9)
    first_hit = np.full(len(test), np.inf)
    first_hit[ray] = np.linalg.norm(loc - center, axis=1)
    visible[test] = first_hit >= dist[test] - tol  # nothing strictly in front of the point
    return visible


def sample_touches(
    mesh: trimesh.Trimesh,
    n: int,
    seed: int,
    policy: TouchPolicy | None = None,
    camera: Camera | None = None,
    sim: EIPSimulator | None = None,
) -> Touches:
    """Sample `n` touches on `mesh` following `policy`, from `seed`.

    Args:
        mesh: the object, world coordinates (watertight, outward normals).
        n: number of touches T >= 1.
        seed: RNG seed; the same (mesh, n, seed, policy, camera, sim configs) gives the same touches.
        policy: the touch policy (default `ConeTouchPolicy()`).
        camera: the view, required when the policy keeps only visible points (`visible_only`).
        sim: optional simulator: when given, touches its pad cannot approach (see `pad_reachable`, e.g. inside a
            hole or between gear teeth narrower than the pad) are rejected, so `simulate_touches` accepts them all.

    Returns:
        :class:`Touches` (positions, directions, normals, strengths).
    """
    policy = policy if policy is not None else ConeTouchPolicy()
    check_mesh(mesh, require_area=True)
    if int(n) < 1:
        raise ValueError(f"n (number of touches) must be >= 1, got {n}")
    return policy.sample(mesh, int(n), np.random.default_rng(seed), camera=camera, sim=sim)


def simulate_touches(
    sim: EIPSimulator,
    mesh: trimesh.Trimesh,
    touches: Touches | Mapping[str, Any],
    batch_size: int = 8,
    progress: bool = False,
) -> list[TactileReading]:
    """Simulate sampled touches with `sim.press_batch`, several touches per solver call.

    Touches sharing a strength are batched together (up to `batch_size` per call); the output follows the
    order of `touches`.

    Args:
        sim: the EIP simulator.
        mesh: the object the touches were sampled on, world coordinates.
        touches: :class:`Touches` from `sample_touches` (or a mapping with "positions" (T, 3), "directions" (T, 3)
            and "strengths" T dicts).
        batch_size: touches per `press_batch` call.
        progress: show a tqdm bar over touches.

    Returns:
        T `TactileReading`, in the order of the touches.
    """
    if not isinstance(touches, Touches):
        missing = [k for k in ("positions", "directions", "strengths") if k not in touches]
        if missing:
            raise ValueError(f"touches must be the Touches returned by sample_touches; missing key {missing[0]!r}")
    get = (lambda k: getattr(touches, k)) if isinstance(touches, Touches) else touches.__getitem__
    pos = torch.as_tensor(get("positions"), dtype=torch.float32)
    dirs = torch.as_tensor(get("directions"), dtype=torch.float32)
    strengths = list(get("strengths"))
    check_shape(pos, "(T, 3)", "positions")
    if dirs.shape != pos.shape or len(strengths) != len(pos):
        raise ValueError(
            f"touches need positions (T, 3), directions (T, 3) and T strengths; got {tuple(pos.shape)}, "
            f"{tuple(dirs.shape)} and {len(strengths)}"
        )
    if int(batch_size) < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(strengths):
        groups.setdefault(tuple(sorted(s.items())), []).append(i)
    readings: list = [None] * len(pos)
    with tqdm(total=len(pos), desc="touches", unit="touch", disable=not progress) as bar:
        for key, idx in groups.items():
            for start in range(0, len(idx), int(batch_size)):
                chunk = idx[start : start + int(batch_size)]
                out = sim.press_batch(mesh, pos[chunk], dirs[chunk], **dict(key))
                for i, reading in zip(chunk, out, strict=True):
                    readings[i] = reading
                bar.update(len(chunk))
    return readings


def resize_tactile(image: Tensor, size: int | tuple[int, int] = 224) -> Tensor:
    """Resize tactile images to the model resolution with kornia (bilinear, antialiased when shrinking).

    Args:
        image: (T, 3, h, w) or (3, h, w) float tactile images (raw simulator resolution).
        size: output side S (square) or (H, W).

    Returns:
        (T, 3, H, W) or (3, H, W), same dtype and device as `image`.
    """
    image = torch.as_tensor(image)
    check_shape(image, "(T, 3, h, w) or (3, h, w)", "image")
    hw = (int(size), int(size)) if isinstance(size, int) else tuple(int(s) for s in size)
    if len(hw) != 2 or min(hw) < 1:
        raise ValueError(f"size must be a positive int or an (H, W) pair, got {size!r}")
    if not image.is_floating_point():
        image = image.float()
    batched = image if image.ndim == 4 else image[None]
    if batched.shape[0] == 0:  # no touches: nothing to interpolate
        return batched.new_zeros((0, 3, *hw))
    if tuple(batched.shape[-2:]) == hw:  # already at the model resolution: the identity, no interpolation round-off
        return image
    shrink = hw[0] < batched.shape[-2] or hw[1] < batched.shape[-1]
    out = kornia.geometry.transform.resize(batched, hw, interpolation="bilinear", align_corners=False, antialias=shrink)
    return out if image.ndim == 4 else out[0]
