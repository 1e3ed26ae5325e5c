"""Contact-cloud classifier: shapes, invariances (touch order, shift of the object), masking, the image branch,
gradient flow and a tiny-batch overfit that needs the patches' geometry."""

import pytest
import torch

from tvrecon.models.components.contact_cloud import ContactCloudClassifier
from tvrecon.models.components.set_pool import masked_max_mean


def _touches(B: int = 2, N: int = 3, Q: int = 16, seed: int = 0) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    tactile = torch.rand(B, N, 3, 8, 8, generator=g)
    points = torch.rand(B, N, Q, 3, generator=g) - 0.5
    normals = torch.nn.functional.normalize(torch.randn(B, N, Q, 3, generator=g), dim=-1)
    mask = torch.rand(B, N, Q, generator=g) > 0.3
    return tactile, points, normals, mask


def _fit(clf: ContactCloudClassifier, inputs: tuple[torch.Tensor, ...], y: torch.Tensor, steps: int) -> None:
    """Adam at 3e-3 on the cross-entropy of one batch, ``steps`` times."""
    opt = torch.optim.Adam(clf.parameters(), lr=3e-3)
    for _ in range(steps):
        loss = torch.nn.functional.cross_entropy(clf(*inputs), y)
        opt.zero_grad()
        loss.backward()
        opt.step()


def test_masked_max_mean_ignores_masked_and_empty_rows() -> None:
    feats = torch.tensor([[[1.0, -2.0], [3.0, 5.0], [100.0, 100.0]], [[7.0, 7.0], [8.0, 8.0], [9.0, 9.0]]])
    mask = torch.tensor([[True, True, False], [False, False, False]])
    out = masked_max_mean(feats, mask)
    torch.testing.assert_close(out, torch.tensor([[3.0, 5.0, 2.0, 1.5], [0.0, 0.0, 0.0, 0.0]]))


@pytest.mark.parametrize("patch_tokens", [False, True])
def test_shapes_and_invariances(patch_tokens: bool) -> None:
    torch.manual_seed(0)
    clf = ContactCloudClassifier(num_classes=5, num_touches=3, points_per_touch=8, patch_tokens=patch_tokens).eval()
    tactile, points, normals, mask = _touches()
    out = clf(tactile, points, normals, mask)
    assert out.shape == (2, 5)
    order = [2, 0, 1]
    torch.testing.assert_close(clf(tactile[:, order], points[:, order], normals[:, order], mask[:, order]), out)
    # the object's position is unknown: a shift of every point changes nothing; a mirrored cloud does
    torch.testing.assert_close(clf(tactile, points + torch.tensor([0.3, -0.2, 0.1]), normals, mask), out)
    assert not torch.allclose(clf(tactile, points * torch.tensor([-1.0, 1.0, 1.0]), normals, mask), out, atol=1e-4)
    # the images are not read without the image branch
    torch.testing.assert_close(clf(torch.zeros_like(tactile), points, normals, mask), out)


@pytest.mark.parametrize("patch_tokens", [False, True])
def test_masked_touches_and_points_are_absent(patch_tokens: bool) -> None:
    torch.manual_seed(0)
    clf = ContactCloudClassifier(num_classes=4, num_touches=3, points_per_touch=8, patch_tokens=patch_tokens).eval()
    tactile, points, normals, mask = _touches(B=1)
    touch_mask = torch.tensor([[True, True, False]])
    junk = points.clone()
    junk[0, 2] = 50.0  # a masked touch
    junk[~mask] = -50.0  # points out of contact
    torch.testing.assert_close(
        clf(tactile, junk, normals, mask, touch_mask), clf(tactile[:, :2], points[:, :2], normals[:, :2], mask[:, :2])
    )
    with pytest.raises(ValueError, match="at least one real touch"):
        clf(tactile, points, normals, mask, torch.zeros(1, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="num_touches"):
        clf(*(x.repeat(1, 2, *([1] * (x.dim() - 2))) for x in (tactile, points, normals, mask)))
    with pytest.raises(ValueError, match=r"\(B, N, Q, 3\)"):
        clf(tactile, points[..., :2], normals, mask)


def test_gradient_reaches_points_and_the_image_branch() -> None:
    torch.manual_seed(0)
    clf = ContactCloudClassifier(num_classes=3, num_touches=3, points_per_touch=8, image_features=True)
    tactile, points, normals, mask = _touches()
    tactile.requires_grad_(True)
    points.requires_grad_(True)
    clf(tactile, points, normals, mask).logsumexp(1).sum().backward()
    assert clf.point_mlp[0].weight.grad.abs().sum() > 0
    assert clf.trunk is not None and clf.trunk.conv1.weight.grad.abs().sum() > 0
    assert (tactile.grad.abs().sum(dim=(2, 3, 4)) > 0).all()  # every touch's image
    assert points.grad[mask].abs().sum() > 0 and points.grad[~mask].abs().sum() == 0  # only contact points


def test_patch_tokens_see_a_touch_without_contact_as_absent_and_carry_gradient() -> None:
    torch.manual_seed(0)
    clf = ContactCloudClassifier(num_classes=4, num_touches=3, points_per_touch=8, patch_tokens=True).eval()
    tactile, points, normals, mask = _touches(B=1)
    mask[0, 2] = False  # the third touch felt nothing: no token, no points
    junk = points.clone()
    junk[0, 2] = 50.0
    torch.testing.assert_close(
        clf(tactile, junk, normals, mask), clf(tactile[:, :2], points[:, :2], normals[:, :2], mask[:, :2])
    )
    clf(tactile, points, normals, mask).logsumexp(1).sum().backward()
    assert clf.patch_mlp is not None and clf.patch_mlp[0].weight.grad.abs().sum() > 0
    assert clf.token_mlp is not None and clf.token_mlp[0].weight.grad.abs().sum() > 0


def test_patch_tokens_tell_apart_clouds_that_differ_only_in_which_touch_felt_what() -> None:
    """Four small clusters of contact points, the same in every sample; class 0 touches them as {1, 2} and {3, 4},
    class 1 as {1, 3} and {2, 4}. The plain PointNet pools all points at once, so it scores both classes the same
    (the control); the patch tokens read each touch's own patch and fit them."""
    torch.manual_seed(0)
    B, N, half = 8, 2, 6
    corners = torch.tensor([[0.4, 0.0, 0.0], [0.0, 0.4, 0.0], [-0.4, 0.0, 0.0], [0.0, -0.3, 0.2]])
    clusters = corners[:, None] + 0.03 * torch.randn(4, half, 3)  # (4, half, 3)
    y = torch.tensor([0, 1] * (B // 2))
    groups = {0: ((0, 1), (2, 3)), 1: ((0, 2), (1, 3))}
    points = torch.stack(
        [torch.stack([torch.cat([clusters[i] for i in touch]) for touch in groups[c]]) for c in y.tolist()]
    )  # (B, N, 2 half, 3)
    normals = torch.nn.functional.normalize(points, dim=-1)
    mask = torch.ones(B, N, 2 * half, dtype=torch.bool)
    tactile = torch.zeros(B, N, 3, 8, 8)
    plain = ContactCloudClassifier(num_classes=2, num_touches=N, points_per_touch=2 * half).eval()
    logits = plain(tactile, points, normals, mask)
    torch.testing.assert_close(logits[0], logits[1])
    clf = ContactCloudClassifier(
        num_classes=2, num_touches=N, points_per_touch=2 * half, dropout=0.0, patch_tokens=True
    )
    _fit(clf, (tactile, points, normals, mask), y, steps=100)
    assert (clf.eval()(tactile, points, normals, mask).argmax(1) == y).all()


@pytest.mark.parametrize("per_touch", [1, 64])
def test_overfits_shapes_that_only_the_geometry_tells_apart(per_touch: int) -> None:
    """4 classes of patches on spheres of 4 radii (same images, normals drawn alike): only the spread of the contact
    points tells the classes apart, and the classifier fits them with whole patches or one point per touch."""
    torch.manual_seed(0)
    B, N, Q = 8, 4, 32
    y = torch.tensor([0, 1, 2, 3, 0, 1, 2, 3])
    radius = (0.1 + 0.1 * y.float())[:, None, None, None]  # (B, 1, 1, 1)
    centres = torch.nn.functional.normalize(torch.randn(B, N, 1, 3), dim=-1)
    normals = torch.nn.functional.normalize(centres + 0.05 * torch.randn(B, N, Q, 3), dim=-1)
    points = radius * normals
    mask = torch.ones(B, N, Q, dtype=torch.bool)
    tactile = torch.zeros(B, N, 3, 8, 8)
    clf = ContactCloudClassifier(num_classes=4, num_touches=N, points_per_touch=per_touch, dropout=0.0)
    _fit(clf, (tactile, points, normals, mask), y, steps=150)
    acc = (clf(tactile, points, normals, mask).argmax(1) == y).float().mean().item()
    assert acc == 1.0, f"train accuracy {acc}"
