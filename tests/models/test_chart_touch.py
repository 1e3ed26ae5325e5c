"""Touch charts of the Chart-based method: the sensor frames, charts fitted over contact points, the U-Net touch branch
and the touch-chart loss."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tvrecon.losses.charts import sampled_chamfer, touch_chart_loss
from tvrecon.models.components.touch_charts import (
    TouchChartPredictor,
    TouchChartUNet,
    fit_touch_charts,
    sensor_frames,
)
from tvrecon.sim.sensor.elastic_pad import sensor_frame


def test_sensor_frames_match_the_pads() -> None:
    dirs = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.3, -0.5, 0.8], [0.0, -2.0, 0.0]])
    R = sensor_frames(dirs)
    for d, r in zip(dirs, R):
        assert torch.allclose(r, sensor_frame(d), atol=1e-6)
    assert torch.allclose(sensor_frames(torch.zeros(1, 3))[0], torch.eye(3))  # padded touch: identity


def _plane_patch(n: int = 9, half: float = 0.2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One touch pressing straight down (-z) on the plane z = 0.5 at (0.1, 0, 0.5): an n x n contact layer."""
    s = torch.linspace(-half, half, n)
    yy, xx = torch.meshgrid(s, s, indexing="ij")
    origin = torch.tensor([0.1, 0.0, 0.5])
    points = torch.stack([xx + 0.1, yy, torch.full_like(xx, 0.5)], dim=-1).reshape(1, -1, 3)
    return points, origin[None], torch.tensor([[0.0, 0.0, -1.0]]), s


def test_fit_touch_charts_spans_the_contact_region() -> None:
    points, origin, direction, _ = _plane_patch()
    mask = torch.zeros(1, 81, dtype=torch.bool)
    mask.view(1, 9, 9)[:, 2:7, 3:8] = True  # a 5 x 5 contact region inside the 9 x 9 layer
    charts, ok = fit_touch_charts(points, mask, origin, direction, size=5)
    assert charts.shape == (1, 25, 3) and bool(ok.all())
    contact = points[mask]  # (25, 3)
    # every chart vertex is a contact point, and the chart covers the whole region (a 5 x 5 region: all of it)
    assert torch.cdist(charts[0], contact).min(dim=1).values.max() < 1e-6
    assert torch.allclose(torch.sort(charts[0], dim=0).values, torch.sort(contact, dim=0).values)
    # no contact, or an empty mask: not ok, zeros
    charts, ok = fit_touch_charts(points, torch.zeros(1, 81, dtype=torch.bool), origin, direction)
    assert not bool(ok.any()) and charts.abs().sum() == 0


def test_fit_touch_charts_bad_input() -> None:
    points, origin, direction, _ = _plane_patch()
    with pytest.raises(ValueError, match="mask must be a"):
        fit_touch_charts(points, torch.ones(1, 80, dtype=torch.bool), origin, direction)
    with pytest.raises(ValueError, match="origins and directions"):
        fit_touch_charts(points, torch.ones(1, 81, dtype=torch.bool), origin[:, :2], direction)


def test_unet_shapes_odd_sizes() -> None:
    net = TouchChartUNet(3, (4, 8, 16))
    assert net(torch.rand(2, 3, 16, 16)).shape == (2, 16, 16)
    assert net(torch.rand(1, 3, 19, 19)).shape == (1, 19, 19)


def test_predictor_places_pixels_on_the_pad() -> None:
    pred = TouchChartPredictor(pad_resolution=(9, 9), pad_spacing=0.5, n_grid=40, domain_size=6.25, channels=(4, 8))
    with torch.no_grad():
        pred.unet.out.weight.zero_()
        pred.unet.out.bias.fill_(0.05)  # every pixel 0.05 above the rest layer
    tactile = torch.zeros(1, 3, 9, 9)
    tactile[:, 2, 3:6, 3:6] = 1.0  # pushed in at the centre
    points, mask = pred(tactile, torch.tensor([[0.1, 0.0, 0.5]]), torch.tensor([[0.0, 0.0, -1.0]]))
    assert points.shape == (1, 81, 3) and mask.shape == (1, 81) and int(mask.sum()) == 9
    cell = 6.25 / 40
    # the rest layer spans (9 - 1) * 0.5 cells, centred on the position; the height lifts along -direction (+z)
    assert torch.allclose(points[0, :, 2], torch.full((81,), 0.55), atol=1e-6)
    assert torch.allclose(points[0, :, 0].max() - points[0, :, 0].min(), torch.tensor(8 * 0.5 * cell), atol=1e-5)
    assert torch.allclose(points[0].mean(0)[:2], torch.tensor([0.1, 0.0]), atol=1e-5)


def test_touch_chart_loss() -> None:
    a = torch.rand(3, 20, 3)
    m = torch.ones(3, 20, dtype=torch.bool)
    assert float(touch_chart_loss(a, m, a, m)) == pytest.approx(0.0, abs=1e-7)
    assert float(touch_chart_loss(a, m, a + 0.1, m)) > 0
    # touches without contact in either set do not count
    m2 = m.clone()
    m2[1:] = False
    far = a.clone()
    far[1:] += 5.0
    assert float(touch_chart_loss(a, m2, far, m)) == pytest.approx(0.0, abs=1e-7)
    none = touch_chart_loss(a.requires_grad_(), torch.zeros_like(m), a, m)
    assert float(none.detach()) == 0.0 and none.requires_grad


def test_sampled_chamfer_skips_zero_area_faces() -> None:
    verts = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [5, 5, 5], [5, 5, 5]]])
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])  # the second face is collapsed far away
    gt = torch.tensor([[[0.2, 0.2, 0.0], [0.5, 0.1, 0.0]]])
    g = torch.Generator().manual_seed(0)
    d = sampled_chamfer(verts, faces, gt, num_samples=500, generator=g)
    assert d.shape == (1,) and float(d) < 0.2  # no sample at (5, 5, 5)


def test_predictor_learns_heights_from_the_touch_chart_loss() -> None:
    torch.manual_seed(0)
    pred = TouchChartPredictor(pad_resolution=(8, 8), pad_spacing=0.5, n_grid=40, domain_size=6.25, channels=(8, 16))
    tactile = torch.zeros(4, 3, 8, 8)
    tactile[:, 2, 2:6, 2:6] = torch.rand(4, 1, 1) + 0.5  # pushed in by a different depth per touch
    pos, dirs = torch.zeros(4, 3), F.normalize(torch.tensor([[0.0, 0.0, -1.0]]).expand(4, 3), dim=-1)
    with torch.no_grad():
        target, mask = pred(tactile, pos, dirs)
        target[..., 2] = 0.1 * tactile[:, 2].reshape(4, -1)  # the exact heights: 0.1 x the normal channel
    opt = torch.optim.Adam(pred.parameters(), lr=3e-3)
    losses = []
    for _ in range(60):
        points, m = pred(tactile, pos, dirs)
        loss = touch_chart_loss(points, m, target, mask)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.2 * losses[0]
