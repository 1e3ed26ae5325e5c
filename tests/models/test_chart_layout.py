"""Chart layout of the Chart-based method: charts on a sphere, seams, touch chart grids and the fused graph."""

from __future__ import annotations

import pytest
import torch

from tvrecon.models.components.charts import ChartTemplate, chart_adjacency, chart_sphere, grid_chart_faces


def test_chart_sphere_sizes_and_orientation() -> None:
    verts, faces, chart = chart_sphere(base_subdivisions=1, chart_subdivisions=5)
    assert verts.shape == (80 * 21, 3) and faces.shape == (80 * 25, 3) and chart.shape == (80 * 21,)
    assert torch.allclose(verts.norm(dim=1), torch.ones(80 * 21), atol=1e-6)  # on the unit sphere
    tri = verts[faces]  # (F, 3, 3)
    normal = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert bool(((normal * tri.mean(1)).sum(-1) > 0).all())  # every face outward
    # faces stay within their chart: the charts are separate meshes
    assert bool((chart[faces] == chart[faces[:, :1]]).all())
    v0, f0, _ = chart_sphere(0, 1)
    assert v0.shape == (60, 3) and f0.shape == (20, 3)  # the icosahedron's 20 faces, one chart each


def test_template_layout_seams_and_touch_faces() -> None:
    t = ChartTemplate(radii=(0.3, 0.3, 0.2), distance=2.0)
    centred = t.verts - torch.tensor([0.0, 0.0, 2.0])
    ellipsoid = (centred / torch.tensor([0.3, 0.3, 0.2])).norm(dim=1)
    assert torch.allclose(ellipsoid, torch.ones_like(ellipsoid), atol=1e-5)
    i, j = t.seams[:, 0], t.seams[:, 1]
    assert bool((i < j).all()) and torch.allclose(t.verts[i], t.verts[j], atol=1e-6)  # same position
    # every chart border vertex is on a seam: 80 charts x 15 border vertices, no interior vertex
    assert t.seam_verts.numel() == 80 * 15
    faces = t.faces_with_touches(3)
    assert faces.shape == (2000 + 3 * 32, 3) and int(faces.max()) == 1680 + 3 * 25 - 1
    assert t.touch_centre == 12 and grid_chart_faces(5).shape == (32, 3)


def test_adjacency_rows_and_touch_links() -> None:
    t = ChartTemplate()
    Vv, Vt = 1680, 25
    used = torch.tensor([[True, False], [False, False]])
    A = chart_adjacency(t, used, 2).to_dense()
    V = Vv + 2 * Vt
    assert A.shape == (2 * V, 2 * V)
    assert torch.allclose(A.sum(1), torch.ones(2 * V))  # row-normalised, self loops included
    assert bool((A.diagonal() > 0).all())
    seam = int(t.seam_verts[0])
    centre0, centre1 = Vv + t.touch_centre, Vv + Vt + t.touch_centre
    assert A[seam, centre0] > 0 and A[centre0, seam] > 0  # a touch in use talks to the vision charts
    assert A[seam, centre1] == 0 and A[centre1, seam] == 0  # a touch not in use does not
    assert A[V + seam, V + centre0] == 0  # the second sample's touch 0 is not in use
    interior = int(torch.tensor([v for v in range(21) if v not in set(t.seam_verts.tolist())])[0])
    assert A[interior, centre0] == 0  # only seam vertices link to touch charts
    assert A[:V, V:].abs().sum() == 0  # samples are independent
    none = chart_adjacency(t, None, 1)
    assert none.shape == (Vv, Vv)
    i, j = t.seams[0].tolist()
    assert none.to_dense()[i, j] > 0
    apart = chart_adjacency(t, None, 1, seams=False).to_dense()  # the authors' vision-only graph
    assert apart[i, j] == 0 and torch.allclose(apart.sum(1), torch.ones(Vv))


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="touch_size must be odd"):
        ChartTemplate(touch_size=4)
    with pytest.raises(ValueError, match="radii must be 3 positive"):
        ChartTemplate(radii=(0.3, 0.3))
    with pytest.raises(ValueError, match="touch_used must have shape"):
        chart_adjacency(ChartTemplate(), torch.ones(3, 2, dtype=torch.bool), 2)
