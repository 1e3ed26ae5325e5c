"""Marker-displacement images: rest grid at zero displacement, a uniform shift moves every dot by that shift."""

from __future__ import annotations

import pytest
import torch

from tvrecon.sim.sensor.markers import marker_displacements, marker_grid, marker_positions, render_markers


def test_marker_grid_is_centred_and_inside_the_pad() -> None:
    m = marker_grid((16, 12), spacing=4.0)
    assert m.shape == (4 * 3, 2) and m.dtype == torch.float32
    assert float(m.min()) > 0 and float(m[:, 0].max()) <= 11 and float(m[:, 1].max()) <= 15
    torch.testing.assert_close(m.mean(0), torch.tensor([5.5, 7.5]))
    with pytest.raises(ValueError, match="spacing"):
        marker_grid((16, 12), spacing=0.0)


def test_zero_displacement_gives_the_rest_grid() -> None:
    m = marker_grid((16, 16), spacing=5.0)
    image = torch.zeros(3, 16, 16)
    torch.testing.assert_close(marker_positions(image, m), m)
    assert float(marker_displacements(image, m, camera_distance=30.0).abs().max()) == 0.0
    dots = render_markers(marker_positions(image, m), (16, 16), radius=1.0, pixels_per_taxel=2)
    assert dots.shape == (32, 32) and float(dots.min()) >= 0 and float(dots.max()) <= 1
    torch.testing.assert_close(dots, render_markers(m, (16, 16), radius=1.0, pixels_per_taxel=2))
    # every dot is centred on its grid point: its coverage-weighted centroid (in taxels) is the marker
    ys, xs = torch.meshgrid((torch.arange(32.0) + 0.5) / 2 - 0.5, (torch.arange(32.0) + 0.5) / 2 - 0.5, indexing="ij")
    for x, y in m.tolist():
        near = ((xs - x) ** 2 + (ys - y) ** 2) < 2.4**2
        w = dots * near
        centroid = torch.stack([(w * xs).sum(), (w * ys).sum()]) / w.sum()
        torch.testing.assert_close(centroid, torch.tensor([x, y]), atol=1e-4, rtol=0)


def test_a_uniform_shift_moves_every_dot_by_the_shift() -> None:
    m = marker_grid((20, 20), spacing=5.0)
    image = torch.zeros(2, 3, 20, 20)  # a batch: rest and shifted
    image[1, 0], image[1, 1] = 0.5, -1.0  # cells; taxel spacing 0.5 -> (1, -2) taxels
    disp = marker_displacements(image, m, taxel_spacing=0.5)
    assert disp.shape == (2, len(m), 2)
    assert float(disp[0].abs().max()) == 0.0
    torch.testing.assert_close(disp[1], torch.tensor([1.0, -2.0]).expand(len(m), 2))
    dots = render_markers(marker_positions(image, m, taxel_spacing=0.5), (20, 20), radius=1.2, pixels_per_taxel=2)
    assert dots.shape == (2, 40, 40)
    shifted = torch.roll(dots[0], shifts=(-4, 2), dims=(0, 1))  # (y, x) taxels * 2 pixels per taxel
    torch.testing.assert_close(dots[1][6:-6, 6:-6], shifted[6:-6, 6:-6], atol=1e-5, rtol=0)
    # batch equals single
    torch.testing.assert_close(marker_positions(image[1], m, 0.5), marker_positions(image, m, 0.5)[1])


def test_pinhole_camera_pushes_dots_outwards_and_bad_input() -> None:
    m = marker_grid((11, 11), spacing=5.0)
    image = torch.zeros(3, 11, 11)
    image[2] = 1.0  # every dot 1 cell closer to a camera 10 cells away
    pos = marker_positions(image, m, camera_distance=10.0)
    torch.testing.assert_close(pos - 5.0, (m - 5.0) * 10.0 / 9.0)
    with pytest.raises(ValueError, match="NaN"):
        marker_positions(torch.full((3, 11, 11), float("nan")), m)
    with pytest.raises(ValueError, match=r"image must have shape \(\.\.\., 3, H, W\), got \(2, 11, 11\)"):
        marker_positions(torch.zeros(2, 11, 11), m)
    with pytest.raises(ValueError, match=r"markers must have shape \(M, 2\), got \(\d+, 1\)"):
        marker_positions(image, m[:, :1])
    with pytest.raises(ValueError, match="camera"):
        marker_positions(image, m, camera_distance=0.5)
