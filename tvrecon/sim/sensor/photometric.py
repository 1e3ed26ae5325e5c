"""RGB tactile images by the GelSight photometric principle, rendered in torch (headless, any device, batched).

A GelSight-like sensor looks at its reflective gel through a camera behind the pad, lit by coloured lights from
different azimuths at a low elevation: each colour channel's brightness follows the surface normal's component
along its light, so the colours encode the surface slope. Here the surface is the contact layer's height field
(the tactile image's normal channel, towards the camera), normals come from central finite differences, and the
shading is Lambertian plus an optional Phong highlight with ambient light. Camera frame = sensor frame: x right
(columns), y up (rows), z towards the camera; a light at azimuth a and elevation e shines from
``(cos e cos a, cos e sin a, sin e)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from tvrecon.utils.shape_check import check_shape

__all__ = ["Light", "DEFAULT_LIGHTS", "surface_normals", "shade", "render_rgb"]


@dataclass(frozen=True)
class Light:
    """A directional coloured light.

    Attributes:
        azimuth: degrees in the pad plane from sensor +x towards +y.
        elevation: degrees above the pad plane, in (0, 90].
        color: (r, g, b) intensity, each >= 0.
    """

    azimuth: float
    elevation: float
    color: tuple[float, float, float]

    def __post_init__(self) -> None:
        if not math.isfinite(float(self.azimuth)):
            raise ValueError(f"Light.azimuth must be finite, got {self.azimuth}")
        if not 0.0 < float(self.elevation) <= 90.0:
            raise ValueError(f"Light.elevation must be in (0, 90] degrees, got {self.elevation}")
        if len(self.color) != 3 or not all(math.isfinite(float(c)) and float(c) >= 0 for c in self.color):
            raise ValueError(f"Light.color must be 3 finite values >= 0, got {self.color}")

    def direction(self, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
        """(3,) unit vector from the surface towards the light."""
        a, e = math.radians(float(self.azimuth)), math.radians(float(self.elevation))
        return torch.tensor(
            [math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)], device=device, dtype=dtype
        )


#: Red, green and blue lights 120 degrees apart at 30 degrees elevation (a flat gel reads (0.5, 0.5, 0.5) + ambient).
DEFAULT_LIGHTS: tuple[Light, ...] = (
    Light(0.0, 30.0, (1.0, 0.0, 0.0)),
    Light(120.0, 30.0, (0.0, 1.0, 0.0)),
    Light(240.0, 30.0, (0.0, 0.0, 1.0)),
)


def surface_normals(height: Tensor, spacing: float = 1.0) -> Tensor:
    """Unit normals of a height field by central finite differences (one-sided at the border).

    Args:
        height: (..., H, W) height towards the camera, H, W >= 2.
        spacing: distance between neighbouring samples, in the units of ``height``.
    Returns:
        (..., 3, H, W) unit normals ``(-dh/dx, -dh/dy, 1) / norm`` (x along columns, y along rows).
    """
    if not isinstance(height, Tensor):
        raise ValueError(f"height must be a (..., H, W) tensor, got {type(height).__name__}")
    check_shape(height, "(..., H, W)", "height")
    if min(height.shape[-2:]) < 2:
        raise ValueError(f"height must have H, W >= 2, got {tuple(height.shape)}")
    if not height.is_floating_point():
        height = height.float()
    if not bool(torch.isfinite(height).all()):
        raise ValueError("height contains NaN or infinite values")
    if not (math.isfinite(float(spacing)) and float(spacing) > 0):
        raise ValueError(f"spacing must be > 0, got {spacing}")
    dy, dx = torch.gradient(height, spacing=float(spacing), dim=(-2, -1))
    n = torch.stack([-dx, -dy, torch.ones_like(height)], dim=-3)
    return n / n.norm(dim=-3, keepdim=True)


def shade(
    normals: Tensor,
    lights: Sequence[Light] = DEFAULT_LIGHTS,
    ambient: float | Sequence[float] = 0.1,
    specular: float = 0.0,
    shininess: float = 20.0,
) -> Tensor:
    """Lambertian + Phong shading of unit normals, viewed from +z (orthographic).

    ``rgb = ambient + sum_l color_l (max(0, n.l) + specular max(0, r_l.v)^shininess)``, ``r_l = 2 (n.l) n - l``,
    clipped to [0, 1].

    Args:
        normals: (..., 3, H, W) unit normals in the sensor frame.
        lights: the lights (at least one). ambient: grey level or (r, g, b), each >= 0.
        specular: Phong highlight weight >= 0 (0 = Lambertian only). shininess: Phong exponent > 0.
    Returns:
        (..., 3, H, W) RGB in [0, 1], the normals' dtype and device.
    """
    if not isinstance(normals, Tensor):
        raise ValueError(f"normals must be a (..., 3, H, W) tensor, got {type(normals).__name__}")
    check_shape(normals, "(..., 3, H, W)", "normals")
    if not bool(torch.isfinite(normals).all()):
        raise ValueError("normals contain NaN or infinite values")
    lights = list(lights)
    if not lights or not all(isinstance(li, Light) for li in lights):
        raise ValueError(f"lights must be a non-empty sequence of Light, got {lights!r}")
    amb = [float(ambient)] * 3 if isinstance(ambient, (int, float)) else [float(a) for a in ambient]
    if len(amb) != 3 or not all(math.isfinite(a) and a >= 0 for a in amb):
        raise ValueError(f"ambient must be a value or (r, g, b), each >= 0, got {ambient}")
    if not float(specular) >= 0 or not float(shininess) > 0:
        raise ValueError(f"specular must be >= 0 and shininess > 0, got {specular} and {shininess}")
    dev, dt = normals.device, normals.dtype
    shape = [1] * (normals.ndim - 3) + [3, 1, 1]
    rgb = torch.tensor(amb, device=dev, dtype=dt).view(shape).expand_as(normals).clone()
    for li in lights:
        ldir = li.direction(dev, dt).view(shape)
        ndotl = (normals * ldir).sum(-3, keepdim=True)  # (..., 1, H, W)
        term = ndotl.clamp_min(0)
        if float(specular) > 0:
            r_z = 2 * ndotl * normals[..., 2:3, :, :] - ldir[..., 2:3, :, :]  # r . v with v = +z
            term = term + float(specular) * r_z.clamp_min(0) ** float(shininess) * (ndotl > 0)
        rgb = rgb + torch.tensor(li.color, device=dev, dtype=dt).view(shape) * term
    return rgb.clamp(0.0, 1.0)


def render_rgb(
    image: Tensor,
    taxel_spacing: float = 0.5,
    lights: Sequence[Light] = DEFAULT_LIGHTS,
    ambient: float | Sequence[float] = 0.1,
    specular: float = 0.0,
    shininess: float = 20.0,
    height_gain: float = 1.0,
) -> Tensor:
    """RGB tactile image of a displacement image (GelSight principle).

    Args:
        image: (..., 3, H, W) displacement in grid cells (``TactileReading.image``); its normal channel (towards
            the camera) is the surface height.
        taxel_spacing: grid cells between neighbouring taxels (``SensorConfig.spacing``).
        lights, ambient, specular, shininess: see :func:`shade`.
        height_gain: exaggerates the height (> 0; real gels show shallow presses brightly).
    Returns:
        (..., 3, H, W) RGB in [0, 1]; a flat (or undeformed) pad gives a uniform image.
    """
    if not isinstance(image, Tensor):
        raise ValueError(f"image must be a (..., 3, H, W) displacement tensor, got {type(image).__name__}")
    check_shape(image, "(..., 3, H, W)", "image")
    if not (math.isfinite(float(height_gain)) and float(height_gain) > 0):
        raise ValueError(f"height_gain must be > 0, got {height_gain}")
    normals = surface_normals(image[..., 2, :, :] * float(height_gain), spacing=taxel_spacing)
    return shade(normals, lights, ambient, specular, shininess)
