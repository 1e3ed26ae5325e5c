"""The elastic sensor pad of EIP: a block of particles on a lattice, its frame and its alpha profile.

The pad lives in its own *sensor frame*: the contact plane is the local xy plane (the contact layer sits at
local z = 0), the pad extends towards +z (towards the robot hand) and the hand presses along local -z. Particles
are ordered ``(layers, H, W)`` with the contact layer first, so ``x[: H * W]`` is the contact layer and
``x[: H * W].reshape(H, W, 3)`` is a tactile image. Pixel ``(i, j)`` sits at local
``x = (j - (W - 1) / 2) * spacing``, ``y = (i - (H - 1) / 2) * spacing`` (in grid cells).

``alpha`` (paper eq. 8, ``v_p = alpha_p * sum_i w_ip v_i + (1 - alpha_p) v_r``) blends the grid velocity with
the hand velocity:

- ``linear`` (the paper): 1 at the contact layer falling linearly to 0 at the back layer (the hand). Positions
  follow the blended velocity while ``F`` follows the grid, so a released pad keeps residual deformation.
- ``clamped`` (default): 1 everywhere except the back layer, which is glued to the hand (0). A released pad
  returns to rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from tvrecon.utils import config_utils
from tvrecon.utils.shape_check import check_shape

ALPHA_PROFILES = ("clamped", "linear")


def _scalar(value: float | Tensor) -> float:
    """Python float of a number or 0-dim tensor (which may require grad)."""
    return float(value.detach()) if isinstance(value, Tensor) else float(value)


@dataclass
class SensorConfig:
    """Geometry and material of the sensor pad.

    Attributes:
        resolution: (H, W) particles of the contact layer (the tactile image size).
        layers: particles through the thickness (>= 2: a contact layer and a back layer).
        spacing: particle spacing in grid cells (0.5 = two particles per cell per axis).
        E: Young's modulus (paper default 3).
        nu: Poisson ratio in [0, 0.5).
        rho: density.
        alpha_profile: ``"clamped"`` (default, returns to rest) or ``"linear"`` (the paper).
        damping: viscous damping rate of the grid velocity (``v_i *= exp(-damping * dt)``), 0 = none.
        mount_mass: mass multiplier of the hand-driven back layer (alpha = 0), modelling the rigid, heavy mount
            the pad is glued to. The eq. 8 blend moves those particles with the hand but their F follows the grid,
            so with ordinary mass the body slips against them and a released pad keeps ~0.5-1 cell of offset; a
            heavy back layer pins the grid velocity at the back to the hand (a kinematic boundary) and the pad
            returns to rest (0.02 cells). None -> 100 for ``clamped``, 1 (the paper, no mount) for ``linear``.
    """

    resolution: tuple[int, int] = (64, 64)
    layers: int = 6
    spacing: float = 0.5
    E: float = 3.0
    nu: float = 0.25
    rho: float = 1.0
    alpha_profile: str = "clamped"
    damping: float = 0.0
    mount_mass: float | None = None

    def __post_init__(self) -> None:
        res = self.resolution
        if isinstance(res, str | bytes) or not hasattr(res, "__len__") or len(res) != 2:
            raise TypeError(f"SensorConfig.resolution must be (H, W), e.g. (64, 64), got {res!r}")
        self.resolution = tuple(config_utils.check_whole(r, "SensorConfig.resolution") for r in res)  # type: ignore[assignment]
        self.validate()

    def validate(self) -> None:
        """Raise ValueError (TypeError for a value that is not a number) naming the bad field and the expected value."""
        config_utils.check_whole(self.layers, "SensorConfig.layers")
        for name in ("spacing", "E", "nu", "rho", "damping"):
            config_utils.check_number(getattr(self, name), f"SensorConfig.{name}")
        if len(self.resolution) != 2 or min(self.resolution) < 2:
            raise ValueError(f"SensorConfig.resolution must be (H, W) with H, W >= 2, got {self.resolution}")
        if int(self.layers) < 2:
            raise ValueError(f"SensorConfig.layers must be >= 2 (a contact layer and a back layer), got {self.layers}")
        if not (0.0 < float(self.spacing) <= 1.0):
            raise ValueError(f"SensorConfig.spacing must be in (0, 1] grid cells, got {self.spacing}")
        E, nu = _scalar(self.E), _scalar(self.nu)
        if not (math.isfinite(E) and E > 0):
            raise ValueError(f"SensorConfig.E (Young's modulus) must be finite and > 0, got {self.E}")
        if not (0.0 <= nu < 0.5):
            raise ValueError(f"SensorConfig.nu (Poisson ratio) must be in [0, 0.5), got {self.nu}")
        if not float(self.rho) > 0:
            raise ValueError(f"SensorConfig.rho must be > 0, got {self.rho}")
        if self.alpha_profile not in ALPHA_PROFILES:
            raise ValueError(f"SensorConfig.alpha_profile must be one of {ALPHA_PROFILES}, got {self.alpha_profile!r}")
        if not float(self.damping) >= 0:
            raise ValueError(f"SensorConfig.damping must be >= 0, got {self.damping}")
        if self.mount_mass is not None and not float(self.mount_mass) >= 1:
            raise ValueError(f"SensorConfig.mount_mass must be >= 1 or None, got {self.mount_mass}")

    @property
    def num_particles(self) -> int:
        """P = layers * H * W."""
        H, W = self.resolution
        return int(self.layers) * H * W

    @property
    def thickness(self) -> float:
        """Distance between the contact layer and the back layer, in grid cells."""
        return (int(self.layers) - 1) * float(self.spacing)

    @property
    def half_extent(self) -> tuple[float, float]:
        """Half size (x, y) of the contact layer from centre to the outermost particle, in grid cells."""
        H, W = self.resolution
        return (W - 1) / 2 * float(self.spacing), (H - 1) / 2 * float(self.spacing)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of the config's fields (`tvrecon.utils.config_utils.field_names`)."""
        return config_utils.field_names(cls)


def pad_lattice(cfg: SensorConfig, device: torch.device | str | None = None) -> Tensor:
    """Rest positions of the pad particles in the sensor frame, in grid cells.

    Returns:
        (P, 3) float32, ordered (layers, H, W) with the contact layer (z = 0) first; z grows towards the hand.
    """
    H, W = cfg.resolution
    s = float(cfg.spacing)
    k = torch.arange(int(cfg.layers), dtype=torch.float32, device=device) * s
    i = (torch.arange(H, dtype=torch.float32, device=device) - (H - 1) / 2) * s
    j = (torch.arange(W, dtype=torch.float32, device=device) - (W - 1) / 2) * s
    kk, ii, jj = torch.meshgrid(k, i, j, indexing="ij")  # (L, H, W) each
    return torch.stack([jj, ii, kk], dim=-1).reshape(-1, 3)  # (P, 3): x along W, y along H, z through thickness


def alpha_profile(cfg: SensorConfig, device: torch.device | str | None = None) -> Tensor:
    """Per-particle alpha_p of paper eq. 8 (eq:particle_v; 1 = follows the grid, 0 = follows the hand).

    Returns:
        (P,) float32 in [0, 1], same particle order as :func:`pad_lattice`.
    """
    H, W = cfg.resolution
    L = int(cfg.layers)
    layer = torch.arange(L, dtype=torch.float32, device=device)
    if cfg.alpha_profile == "linear":
        per_layer = 1.0 - layer / (L - 1)
    elif cfg.alpha_profile == "clamped":
        per_layer = (layer < L - 1).to(torch.float32)
    else:
        raise ValueError(f"alpha_profile must be one of {ALPHA_PROFILES}, got {cfg.alpha_profile!r}")
    return per_layer[:, None].expand(L, H * W).reshape(-1).contiguous()


def mass_scale(cfg: SensorConfig, device: torch.device | str | None = None) -> Tensor:
    """Per-particle mass multiplier: ``mount_mass`` on the hand-driven back layer, 1 elsewhere.

    Returns:
        (P,) float32 >= 1, same particle order as :func:`pad_lattice`.
    """
    mount = cfg.mount_mass if cfg.mount_mass is not None else (100.0 if cfg.alpha_profile == "clamped" else 1.0)
    alpha = alpha_profile(cfg, device=device)
    return torch.where(alpha == 0, torch.full_like(alpha, float(mount)), torch.ones_like(alpha))


def contact_layer(x: Tensor, cfg: SensorConfig) -> Tensor:
    """The contact layer of a pad as an image grid.

    Args:
        x: (P, 3) or (..., P, 3) particle quantities in pad order.
    Returns:
        (..., H, W, 3) view of the first H * W particles.
    """
    check_shape(x, "(..., P, 3)", "x")
    H, W = cfg.resolution
    if x.shape[-2] < H * W:
        raise ValueError(f"x must have shape (..., P, 3) with P >= H*W = {H * W}, got {tuple(x.shape)}")
    return x[..., : H * W, :].reshape(*x.shape[:-2], H, W, 3)


def sensor_frame(direction: Tensor) -> Tensor:
    """Orthonormal sensor frame for a press direction.

    The local z axis points against the press (``e_z = -direction``); the local x axis is the world x axis
    projected onto the contact plane (or the world y axis when the press is along x), ``e_y = e_z x e_x``. This is
    the helper-axis rule of `tvrecon.utils.geometry.perpendicular_basis` (e_x = -e2 there, up to rounding), computed
    here in float32 torch because these exact values set the pad's in-plane orientation of every tactile image.

    Args:
        direction: (3,) press direction in world coordinates (pointing into the object), any non-zero length.
    Returns:
        (3, 3) float32 rotation R whose columns are (e_x, e_y, e_z) in world coordinates, det R = +1;
        world = R @ local.
    """
    d = torch.as_tensor(direction, dtype=torch.float32)
    check_shape(d, "(3,)", "direction")
    if not bool(torch.isfinite(d).all()):
        raise ValueError(f"direction must be finite, got {d.tolist()}")
    n = torch.linalg.vector_norm(d)
    if float(n) < 1e-8:
        raise ValueError(f"direction must be a non-zero vector (the press direction into the object), got {d.tolist()}")
    ez = -d / n
    ref = torch.tensor([1.0, 0.0, 0.0], device=d.device) if abs(float(ez[0])) < 0.9 else torch.tensor([0.0, 1.0, 0.0])
    ref = ref.to(d.device)
    ex = ref - (ref @ ez) * ez
    ex = ex / torch.linalg.vector_norm(ex)
    ey = torch.linalg.cross(ez, ex)
    return torch.stack([ex, ey, ez], dim=1)
