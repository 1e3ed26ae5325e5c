"""Pictures and exports: tactile PNG, sequence PNG, PLY, pad surface mesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from PIL import Image

from tvrecon.sim.plots import save_ply, save_sequence_png, save_tactile_png
from tvrecon.sim.sensor import SensorConfig, pad_lattice
from tvrecon.sim.sensor.surface import pad_surface


def _bump(H: int = 16, W: int = 20, amp: float = 1.0) -> torch.Tensor:
    y, x = torch.meshgrid(torch.linspace(-1, 1, H), torch.linspace(-1, 1, W), indexing="ij")
    z = amp * torch.exp(-4 * (x**2 + y**2))
    return torch.stack([0.2 * x * z, 0.2 * y * z, z])  # (3, H, W)


def test_tactile_png(tmp_path: Path) -> None:
    out = save_tactile_png(_bump(), tmp_path / "sub" / "t.png", title="bump")
    img = np.asarray(Image.open(out))
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert img[..., :3].std() > 10  # not blank
    assert not list(out.parent.glob(".*.tmp"))  # atomic: no temp files left


def test_sequence_png_with_sections(tmp_path: Path) -> None:
    frames = torch.stack([_bump(amp=a) for a in (0.0, 0.5, 1.0)])
    sections = [np.random.default_rng(k).normal(size=(30, 3)) for k in range(3)]
    out = save_sequence_png(frames, tmp_path / "seq.png", steps=[0, 10, 20], sections=sections)
    w, h = Image.open(out).size
    assert w > 1.5 * h  # side by side
    with pytest.raises(ValueError, match=r"frames must have shape \(K, 3, H, W\), got \(3, "):
        save_sequence_png(frames[0], tmp_path / "bad.png")
    with pytest.raises(ValueError, match="steps must have K=3"):
        save_sequence_png(frames, tmp_path / "bad.png", steps=[1])


def test_bad_tactile_image(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\(3, H, W\)"):
        save_tactile_png(torch.zeros(2, 4, 4), tmp_path / "x.png")
    bad = _bump()
    bad[2, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        save_tactile_png(bad, tmp_path / "x.png")


def test_ply_roundtrip(tmp_path: Path) -> None:
    pts = torch.rand(50, 3)
    out = save_ply(pts, tmp_path / "pad.ply", values=pts[:, 2])
    cloud = trimesh.load(out)
    assert len(cloud.vertices) == 50
    np.testing.assert_allclose(np.asarray(cloud.vertices), pts.numpy(), atol=1e-6)
    with pytest.raises(ValueError, match=r"points must have shape \(P, 3\), got \(4, 2\)"):
        save_ply(torch.zeros(4, 2), tmp_path / "bad.ply")
    with pytest.raises(ValueError, match=r"points must have shape \(P, 3\) with P > 0"):
        save_ply(torch.zeros(0, 3), tmp_path / "bad.ply")
    with pytest.raises(ValueError, match=r"values must have shape \(P,\)"):
        save_ply(pts, tmp_path / "bad.ply", values=torch.zeros(3))


def test_pad_surface_encloses_the_block() -> None:
    cfg = SensorConfig(resolution=(8, 10), layers=4, spacing=0.5)
    pts = pad_lattice(cfg)
    mesh = pad_surface(pts, spacing=cfg.spacing)
    assert mesh.is_watertight
    lo, hi = pts.min(0).values.numpy(), pts.max(0).values.numpy()
    # the surface sits about half a spacing outside the outermost particle centres
    np.testing.assert_allclose(mesh.bounds[0], lo - 0.25, atol=0.3)
    np.testing.assert_allclose(mesh.bounds[1], hi + 0.25, atol=0.3)
    assert mesh.volume == pytest.approx(float(np.prod(hi - lo + 0.5)), rel=0.35)
    with pytest.raises(ValueError, match=r"points must have shape \(P, 3\) with P >= 4"):
        pad_surface(torch.zeros(3, 3), spacing=0.5)
    with pytest.raises(ValueError, match=r"points must have shape \(P, 3\), got \(5, 2\)"):
        pad_surface(torch.zeros(5, 2), spacing=0.5)
