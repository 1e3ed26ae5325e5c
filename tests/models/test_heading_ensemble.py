"""The heading ensemble: K turns of a touch set's 3D inputs about +z, class probabilities averaged."""

import math

import pytest
import torch
from torch import nn

from tvrecon.data.pose_augment import turn_about_up
from tvrecon.models.components.contact_cloud import ContactCloudClassifier
from tvrecon.models.heading_ensemble import check_headings, heading_ensemble
from tvrecon.models.lit_cls import ClassificationModule

NAMES = ("tactile", "patch_points", "patch_normals", "patch_mask")


def _inputs(B: int = 3, N: int = 2, Q: int = 5) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return [
        torch.rand(B, N, 3, 4, 4, generator=g),
        torch.randn(B, N, Q, 3, generator=g),
        torch.nn.functional.normalize(torch.randn(B, N, Q, 3, generator=g), dim=-1),
        torch.ones(B, N, Q, dtype=torch.bool),
    ]


class _XReader(nn.Module):
    """Logits from the mean x coordinate of the points: not invariant to a turn about +z."""

    def forward(self, tactile, points, normals, mask):  # noqa: ANN001, ANN201
        x = points[..., 0].mean((1, 2))  # (B,)
        return torch.stack([x, -x, torch.zeros_like(x)], dim=1)


class _RadialReader(nn.Module):
    """Logits from the points' distance to the z axis and their height: invariant to any turn about +z."""

    def forward(self, tactile, points, normals, mask):  # noqa: ANN001, ANN201
        r = points[..., :2].norm(dim=-1).mean((1, 2))
        z = points[..., 2].mean((1, 2))
        return torch.stack([r, z, r * z], dim=1)


def test_one_heading_is_the_networks_own_answer():
    inputs = _inputs()
    net = _XReader()
    out = heading_ensemble(net, inputs, NAMES, 1)
    assert torch.allclose(out, torch.log_softmax(net(*inputs), dim=-1))


def test_an_invariant_network_gives_the_same_answer_at_every_count():
    inputs = _inputs()
    one = heading_ensemble(_RadialReader(), inputs, NAMES, 1)
    for k in (2, 5, 8):
        assert torch.allclose(heading_ensemble(_RadialReader(), inputs, NAMES, k), one, atol=1e-5)


def test_four_headings_average_the_quarter_turns():
    inputs = _inputs()
    net = _XReader()
    probs = []
    for j in range(4):
        turned = [inputs[0], turn_about_up(inputs[1], j * math.pi / 2), turn_about_up(inputs[2], j * math.pi / 2)]
        probs.append(torch.softmax(net(*turned, inputs[3]), dim=-1))
    expected = torch.stack(probs).mean(0)
    got = heading_ensemble(net, inputs, NAMES, 4).exp()
    assert torch.allclose(got, expected, atol=1e-6)
    # opposite headings cancel the x reading: the answer is not the single heading's
    assert not torch.allclose(got, probs[0], atol=1e-3)
    assert torch.allclose(got.sum(1), torch.ones(3))


def test_bad_heading_counts_are_clear_errors():
    with pytest.raises(ValueError, match="headings must be >= 1"):
        check_headings(0, NAMES)
    with pytest.raises(ValueError, match="reads only"):
        check_headings(4, ("tactile",))
    assert check_headings(1, ("tactile",)) == 1
    with pytest.raises(ValueError, match="inputs for"):
        heading_ensemble(_XReader(), _inputs()[:2], NAMES, 2)


def test_the_module_evaluates_over_headings_and_refuses_an_image_only_network():
    net = ContactCloudClassifier(num_classes=4, num_touches=2, points_per_touch=5, width=8)
    plain = ClassificationModule(net, optimizer=torch.optim.Adam, num_touches=2).eval()
    turned = ClassificationModule(net, optimizer=torch.optim.Adam, num_touches=2, headings=3).eval()
    inputs = _inputs()
    with torch.no_grad():
        assert torch.equal(plain.evaluate(*inputs), net(*inputs))  # headings=1: the logits, bit for bit
        assert torch.allclose(turned.evaluate(*inputs), heading_ensemble(net, inputs, NAMES, 3))
    image_net = nn.Conv2d(3, 4, 1)  # reads images only (the default touch_inputs)
    with pytest.raises(ValueError, match="use headings=1"):
        ClassificationModule(image_net, optimizer=torch.optim.Adam, num_touches=1, headings=2)
