"""Chamfer distance against a naive python-loop reference."""

import pytest
import torch

from tvrecon.losses.chamfer import ChamferDistance, chamfer_distance, chamfer_terms, nearest_neighbors


def naive_chamfer(x: torch.Tensor, y: torch.Tensor) -> tuple[float, list[int], list[int]]:
    """Per-sample chamfer of (N,3) and (M,3) with python loops."""
    dxy, ixy = [], []
    for p in x.tolist():
        d = [sum((a - b) ** 2 for a, b in zip(p, q)) for q in y.tolist()]
        ixy.append(min(range(len(d)), key=d.__getitem__))
        dxy.append(min(d))
    dyx, iyx = [], []
    for q in y.tolist():
        d = [sum((a - b) ** 2 for a, b in zip(p, q)) for p in x.tolist()]
        iyx.append(min(range(len(d)), key=d.__getitem__))
        dyx.append(min(d))
    return sum(dxy) / len(dxy) + sum(dyx) / len(dyx), ixy, iyx


def test_chamfer_matches_naive_reference() -> None:
    x, y = torch.rand(3, 7, 3), torch.rand(3, 5, 3)
    res = chamfer_terms(x, y, reduction="none")
    for b in range(3):
        ref, ixy, iyx = naive_chamfer(x[b], y[b])
        assert res.loss[b].item() == pytest.approx(ref, rel=1e-5)
        assert res.idx_xy[b].tolist() == ixy
        assert res.idx_yx[b].tolist() == iyx
    assert chamfer_distance(x, y).item() == pytest.approx(res.loss.mean().item(), rel=1e-6)
    assert chamfer_distance(x, y, reduction="sum").item() == pytest.approx(res.loss.sum().item(), rel=1e-6)
    assert ChamferDistance("none")(x, y).shape == (3,)


def test_chamfer_known_value_and_zero() -> None:
    x = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    y = torch.tensor([[[0.0, 0.0, 2.0]]])
    # x->y: (4 + 5) / 2 = 4.5 ; y->x: 4 ; total 8.5
    assert chamfer_distance(x, y).item() == pytest.approx(8.5)
    assert chamfer_distance(x, x).item() == 0.0


def test_chamfer_lengths_ignore_padding() -> None:
    x, y = torch.rand(2, 6, 3), torch.rand(2, 8, 3)
    x_len, y_len = torch.tensor([4, 6]), torch.tensor([8, 3])
    padded_x, padded_y = x.clone(), y.clone()
    padded_x[0, 4:] = 100.0
    padded_y[1, 3:] = -100.0
    got = chamfer_distance(padded_x, padded_y, x_len, y_len, reduction="none")
    for b in range(2):
        ref, _, _ = naive_chamfer(x[b, : x_len[b]], y[b, : y_len[b]])
        assert got[b].item() == pytest.approx(ref, rel=1e-5)


def test_chamfer_gradient_matches_finite_difference() -> None:
    x = torch.rand(1, 5, 3, dtype=torch.float64, requires_grad=True)
    y = torch.rand(1, 6, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda a: chamfer_distance(a, y), (x,))


def test_chamfer_validates_input() -> None:
    with pytest.raises(ValueError, match=r"\(B, N, 3\)"):
        chamfer_distance(torch.rand(5, 3), torch.rand(1, 5, 3))
    with pytest.raises(ValueError, match="reduction"):
        chamfer_distance(torch.rand(1, 5, 3), torch.rand(1, 5, 3), reduction="max")
    with pytest.raises(ValueError, match="batch size"):
        chamfer_distance(torch.rand(2, 5, 3), torch.rand(1, 5, 3))


def test_nearest_neighbors_far_from_origin_and_chunked() -> None:
    """Clouds at camera distance (z ~ 2) and several chunks: same neighbours as a float64 brute force (no near-ties
    in these random clouds), distances to float32 round-off."""
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 300, 3, generator=g) * 0.3 + torch.tensor([0.1, -0.2, 2.0])
    y = torch.randn(2, 200, 3, generator=g) * 0.3 + torch.tensor([0.1, -0.2, 2.0])
    dist, idx = nearest_neighbors(x, y, chunk=64)
    exact = torch.cdist(x.double(), y.double()).square()  # (2, 300, 200)
    best = exact.min(-1)
    gap = exact.topk(2, dim=-1, largest=False).values.diff(dim=-1)[..., 0]  # distance to the runner-up
    clear = gap > 1e-5
    assert clear.float().mean() > 0.95
    assert torch.equal(idx[clear], best.indices[clear])
    assert torch.allclose(dist.double(), best.values, atol=1e-6)
    mask = torch.ones(2, 200, dtype=torch.bool)
    mask[:, best.indices[0, 0]] = False  # hide x[0, 0]'s nearest point: the runner-up is chosen
    _, idx_m = nearest_neighbors(x, y, mask)
    assert idx_m[0, 0].item() == exact[0, 0].topk(2, largest=False).indices[1].item()
    assert bool(mask.gather(1, idx_m).all())
