"""GelSight-style RGB rendering: flat is uniform, a bump's colours follow its slope towards each light."""

from __future__ import annotations

import math

import pytest
import torch

from tvrecon.sim.sensor.photometric import DEFAULT_LIGHTS, Light, render_rgb, shade, surface_normals


def _bump(n: int = 33, height: float = 3.0, sigma: float = 5.0) -> torch.Tensor:
    """(3, n, n) displacement image with a Gaussian bump in the normal channel."""
    i, j = torch.meshgrid(torch.arange(n, dtype=torch.float32), torch.arange(n, dtype=torch.float32), indexing="ij")
    c = (n - 1) / 2
    img = torch.zeros(3, n, n)
    img[2] = height * torch.exp(-((i - c) ** 2 + (j - c) ** 2) / (2 * sigma**2))
    return img


def test_flat_surface_gives_a_uniform_image() -> None:
    for image in (torch.zeros(3, 8, 10), torch.full((3, 8, 10), 0.7)):  # rest, or pressed flat everywhere
        rgb = render_rgb(image, ambient=0.1)
        assert rgb.shape == (3, 8, 10)
        expected = torch.tensor([0.1 + 0.5, 0.1 + 0.5, 0.1 + 0.5])  # sin(30 deg) per light
        torch.testing.assert_close(rgb, expected[:, None, None].expand(3, 8, 10))


def test_bump_colours_follow_the_light_directions() -> None:
    img = _bump()
    rgb = render_rgb(img, taxel_spacing=0.5, ambient=0.0)
    n = surface_normals(img[2], spacing=0.5)
    c, r = 16, 6  # centre, and a radius on the bump's flank
    for ch, light in enumerate(DEFAULT_LIGHTS):
        a = math.radians(light.azimuth)
        toward = (round(c + r * math.sin(a)), round(c + r * math.cos(a)))  # (row = y, col = x)
        away = (round(c - r * math.sin(a)), round(c - r * math.cos(a)))
        assert float(rgb[ch][toward]) > float(rgb[ch][away]) + 0.2, light
        # each channel is exactly its light's Lambertian term
        ldir = light.direction()
        torch.testing.assert_close(rgb[ch], (n * ldir[:, None, None]).sum(0).clamp(0, 1))
        # the brightest pixel of the channel lies on the flank facing its light
        k = int(rgb[ch].argmax())
        ang = math.atan2(k // 33 - c, k % 33 - c)
        assert abs(math.remainder(ang - a, 2 * math.pi)) < math.radians(25), (light, math.degrees(ang))


def test_batch_equals_single_and_specular() -> None:
    imgs = torch.stack([_bump(height=h) for h in (0.5, 2.0, 4.0)]).reshape(3, 1, 3, 33, 33)
    rgb = render_rgb(imgs, specular=0.5, shininess=8.0)
    assert rgb.shape == (3, 1, 3, 33, 33)
    for b in range(3):
        torch.testing.assert_close(rgb[b, 0], render_rgb(imgs[b, 0], specular=0.5, shininess=8.0))
    assert float(rgb.max()) <= 1.0 and float(rgb.min()) >= 0.0
    assert float((rgb - render_rgb(imgs)).abs().max()) > 0.01  # the highlight adds light


def test_bad_input_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"image must have shape \(\.\.\., 3, H, W\), got \(8, 8\)"):
        render_rgb(torch.zeros(8, 8))
    with pytest.raises(ValueError, match="NaN"):
        render_rgb(torch.full((3, 4, 4), float("nan")))
    with pytest.raises(ValueError, match="elevation"):
        Light(0.0, 0.0, (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="color"):
        Light(0.0, 30.0, (1.0, 1.0))
    with pytest.raises(ValueError, match="lights"):
        shade(torch.zeros(3, 4, 4), lights=[])
    with pytest.raises(ValueError, match="ambient"):
        render_rgb(torch.zeros(3, 4, 4), ambient=(0.1, 0.1))
