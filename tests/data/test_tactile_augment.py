"""rotate_tactile: grid and shear vectors turned together, in the simulator's pixel convention."""

import math

import pytest
import torch

from tvrecon.data.tactile_augment import orient_touches, rotate_tactile
from tvrecon.sim.sensor import SensorConfig, pad_lattice

H = W = 7


def _field_image(Q: torch.Tensor) -> torch.Tensor:
    """(3, H, W) image of a non-symmetric analytic touch turned by the 2x2 orthogonal Q.

    The touch is u(p) = A p + b (in-plane), n(p) = x + 2 y^2 (normal) at the pad's local pixel coordinates p = (x, y)
    taken from :func:`pad_lattice` (the simulator's convention). The turned touch is u'(p) = Q u(Q^T p),
    n'(p) = n(Q^T p).
    """
    cfg = SensorConfig(resolution=(H, W), layers=2, spacing=1.0)
    p = pad_lattice(cfg)[: H * W, :2].double()  # (HW, 2) local (x, y), pixel order (i, j)
    A = torch.tensor([[0.3, -1.1], [0.7, 0.2]], dtype=torch.float64)
    b = torch.tensor([0.5, -0.25], dtype=torch.float64)
    q = p @ Q  # Q^T p as rows
    u = (q @ A.T + b) @ Q.T
    n = q[:, 0] + 2 * q[:, 1] ** 2
    return torch.cat([u, n[:, None]], dim=1).reshape(H, W, 3).permute(2, 0, 1)


def _turn(k: int) -> torch.Tensor:
    a = k * math.pi / 2
    return torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=torch.float64).round()


MIRROR = torch.tensor([[-1.0, 0.0], [0.0, 1.0]], dtype=torch.float64)  # x -> -x


@pytest.mark.parametrize("k", [0, 1, 2, 3, -1, 5])
@pytest.mark.parametrize("mirror", [False, True])
def test_matches_the_turned_analytic_touch(k: int, mirror: bool) -> None:
    identity = torch.eye(2, dtype=torch.float64)
    image = _field_image(identity)
    Q = _turn(k) @ (MIRROR if mirror else identity)  # mirror first, then turn
    expected = _field_image(Q)
    assert torch.allclose(rotate_tactile(image, k, mirror), expected, atol=1e-12)
    if k % 4:  # a grid-only turn (shear vectors left alone) is wrong
        wrong = torch.rot90(image, k, dims=(-1, -2))
        assert not torch.allclose(wrong, expected, atol=1e-3)


def test_group_structure_batches_and_gradients() -> None:
    x = torch.randn(2, 4, 3, 5, 5, requires_grad=True)
    assert torch.equal(rotate_tactile(x, 4), x)
    y = x
    for _ in range(4):
        y = rotate_tactile(y, 1)
    assert torch.equal(y, x)
    assert torch.equal(rotate_tactile(rotate_tactile(x, 0, True), 0, True), x)
    assert torch.equal(rotate_tactile(rotate_tactile(x, 1), 3), x)
    out = rotate_tactile(x, 3, True)
    assert out.shape == x.shape and out.dtype == x.dtype
    assert torch.allclose(out.norm(dim=2).sum(), x.norm(dim=2).sum())  # vector lengths preserved
    out.sum().backward()
    assert x.grad is not None
    rect = torch.randn(3, 4, 6)
    assert rotate_tactile(rect, 2, True).shape == (3, 4, 6)
    per_touch = orient_touches(x[0].detach(), [0, 1, 2, 3], [False, True, False, True])
    for t, (k, m) in enumerate([(0, False), (1, True), (2, False), (3, True)]):
        assert torch.equal(per_touch[t], rotate_tactile(x[0, t].detach(), k, m))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU")
def test_same_on_gpu() -> None:
    x = torch.randn(4, 3, 6, 6)
    assert torch.equal(rotate_tactile(x.cuda(), 1, True).cpu(), rotate_tactile(x, 1, True))


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="square"):
        rotate_tactile(torch.zeros(3, 4, 6), 1)
    with pytest.raises(ValueError, match=r"images must have shape \(\.\.\., 3, H, W\), got \(2, 4, 4\)"):
        rotate_tactile(torch.zeros(2, 4, 4), 1)
    with pytest.raises(ValueError, match=r"images must have shape \(N, 3, H, W\), got \(3, 4, 4\)"):
        orient_touches(torch.zeros(3, 4, 4), [1], [False])
    with pytest.raises(TypeError, match="integer"):
        rotate_tactile(torch.zeros(3, 4, 4), 1.5)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="integer"):
        rotate_tactile(torch.zeros(3, 4, 4), True)
    with pytest.raises(TypeError, match="torch.Tensor"):
        rotate_tactile([[0.0]], 1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="one k and one mirror"):
        orient_touches(torch.zeros(2, 3, 4, 4), [1], [False, True])
