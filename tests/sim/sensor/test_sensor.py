"""Sensor pad: lattice, alpha profiles, mount mass, sensor frame, config validation."""

from __future__ import annotations

import pytest
import torch

from tvrecon.sim.sensor import SensorConfig, alpha_profile, pad_lattice, sensor_frame
from tvrecon.sim.sensor.elastic_pad import contact_layer, mass_scale


def test_pad_lattice_layout() -> None:
    cfg = SensorConfig(resolution=(4, 6), layers=3, spacing=0.5)
    x = pad_lattice(cfg)
    assert x.shape == (cfg.num_particles, 3) == (72, 3) and x.dtype == torch.float32
    img = contact_layer(x, cfg)  # (H, W, 3): the first H*W particles
    assert img.shape == (4, 6, 3)
    assert torch.all(img[..., 2] == 0)  # contact layer at z = 0
    assert float(x[:, 2].max()) == pytest.approx(cfg.thickness) == pytest.approx(1.0)  # back layer towards +z
    torch.testing.assert_close(img[0, 1] - img[0, 0], torch.tensor([0.5, 0.0, 0.0]))  # W along x
    torch.testing.assert_close(img[1, 0] - img[0, 0], torch.tensor([0.0, 0.5, 0.0]))  # H along y
    torch.testing.assert_close(img[..., :2].mean((0, 1)), torch.zeros(2))  # centred
    assert cfg.half_extent == (1.25, 0.75)


def test_alpha_profiles_and_mount() -> None:
    clamped = SensorConfig(resolution=(2, 3), layers=4)
    a = alpha_profile(clamped).reshape(4, 6)
    assert torch.all(a[:3] == 1) and torch.all(a[3] == 0)  # only the back layer follows the hand
    linear = SensorConfig(resolution=(2, 3), layers=4, alpha_profile="linear")
    b = alpha_profile(linear).reshape(4, 6)
    torch.testing.assert_close(b[:, 0], torch.tensor([1.0, 2 / 3, 1 / 3, 0.0]))  # 1 at contact -> 0 at the hand
    assert torch.all(mass_scale(clamped).reshape(4, 6)[3] == 100) and torch.all(mass_scale(clamped)[:18] == 1)
    assert torch.all(mass_scale(linear) == 1)  # the paper: no mount
    assert torch.all(mass_scale(SensorConfig(layers=2, mount_mass=7.0)).reshape(2, -1)[1] == 7)


@pytest.mark.parametrize("d", [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.4, 0.2], [-1.0, 1e-9, 0.0]])
def test_sensor_frame_is_a_rotation_pressing_along_minus_z(d: list[float]) -> None:
    R = sensor_frame(torch.tensor(d))
    assert R.shape == (3, 3)
    torch.testing.assert_close(R.T @ R, torch.eye(3), atol=1e-6, rtol=0)
    assert float(torch.linalg.det(R)) == pytest.approx(1.0, abs=1e-6)
    unit = torch.tensor(d) / torch.tensor(d).norm()
    torch.testing.assert_close(R @ torch.tensor([0.0, 0.0, -1.0]), unit, atol=1e-6, rtol=0)  # local -z = press


def test_sensor_frame_rejects_bad_directions() -> None:
    with pytest.raises(ValueError, match="non-zero"):
        sensor_frame(torch.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        sensor_frame(torch.tensor([float("nan"), 0.0, 1.0]))
    with pytest.raises(ValueError, match=r"direction must have shape \(3,\), got \(2,\)"):
        sensor_frame(torch.ones(2))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(layers=1), "layers"),
        (dict(resolution=(1, 8)), "resolution"),
        (dict(spacing=0.0), "spacing"),
        (dict(E=-1.0), "Young"),
        (dict(nu=0.5), "Poisson"),
        (dict(alpha_profile="cubic"), "alpha_profile"),
        (dict(damping=-1.0), "damping"),
        (dict(mount_mass=0.5), "mount_mass"),
    ],
)
def test_sensor_config_validation(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SensorConfig(**kwargs)


def test_contact_layer_shape_check() -> None:
    with pytest.raises(ValueError, match=r"x must have shape \(\.\.\., P, 3\) with P >= H\*W = 16, got \(5, 3\)"):
        contact_layer(torch.zeros(5, 3), SensorConfig(resolution=(4, 4)))
    with pytest.raises(ValueError, match=r"x must have shape \(\.\.\., P, 3\), got \(16, 2\)"):
        contact_layer(torch.zeros(16, 2), SensorConfig(resolution=(4, 4)))
