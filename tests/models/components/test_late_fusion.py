"""Late fusion of trained classifiers: every member asked on the same touches, the class probabilities combined."""

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.models.components.contact_cloud import ContactCloudClassifier
from tvrecon.models.components.late_fusion import LateFusionClassifier


class _Fixed(nn.Module):
    """Returns the same logits for every sample; reads the inputs named ``touch_inputs``."""

    def __init__(self, logits: list[float], touch_inputs: tuple[str, ...] = ("tactile",), num_touches: int = 10):
        super().__init__()
        self.register_buffer("logits", torch.tensor(logits))
        self.touch_inputs = touch_inputs
        self.num_touches = num_touches

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        assert len(inputs) == len(self.touch_inputs)
        return self.logits.expand(inputs[0].shape[0], -1)


def _patch_inputs(B: int = 2, N: int = 3, Q: int = 6) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    return [
        torch.rand(B, N, 3, 8, 8, generator=g),
        torch.randn(B, N, Q, 3, generator=g),
        F.normalize(torch.randn(B, N, Q, 3, generator=g), dim=-1),
        torch.ones(B, N, Q, dtype=torch.bool),
    ]


def test_mean_prob_is_the_log_of_the_average_probability() -> None:
    a, b = _Fixed([2.0, 0.0, -1.0]), _Fixed([-1.0, 1.0, 0.5])
    fused = LateFusionClassifier([a, b], rule="mean_prob")
    out = fused(torch.zeros(4, 2, 3, 5, 5))  # (B, C)
    expected = torch.log((F.softmax(a.logits, -1) + F.softmax(b.logits, -1)) / 2)
    assert out.shape == (4, 3)
    torch.testing.assert_close(out, expected.expand(4, 3))
    torch.testing.assert_close(out.exp().sum(-1), torch.ones(4))


def test_mean_log_prob_is_the_normalised_geometric_mean() -> None:
    a, b = _Fixed([2.0, 0.0, -1.0]), _Fixed([-1.0, 1.0, 0.5])
    out = LateFusionClassifier([a, b], rule="mean_log_prob")(torch.zeros(1, 2, 3, 5, 5))
    geo = torch.sqrt(F.softmax(a.logits, -1) * F.softmax(b.logits, -1))
    torch.testing.assert_close(out[0], torch.log(geo / geo.sum()))
    # the rules differ: one member sure of class 0, another sure it is not, two lukewarm on class 1
    sure, against = _Fixed([6.0, 0.0, 0.0]), _Fixed([-6.0, 0.3, 0.0])
    by_mean = LateFusionClassifier([sure, against], "mean_prob")(torch.zeros(1, 1, 3, 2, 2)).argmax(-1)
    by_geo = LateFusionClassifier([sure, against], "mean_log_prob")(torch.zeros(1, 1, 3, 2, 2)).argmax(-1)
    assert int(by_mean) == 0 and int(by_geo) == 1


def test_a_classifier_fused_with_itself_answers_as_it_does_alone() -> None:
    torch.manual_seed(0)
    net = TactileClassifier(num_classes=5, num_touches=3).eval()
    x = torch.rand(4, 3, 3, 16, 16)
    for rule in ("mean_prob", "mean_log_prob"):
        fused = LateFusionClassifier([net, net], rule)
        torch.testing.assert_close(fused(x), F.log_softmax(net(x), -1), rtol=1e-5, atol=1e-5)


def test_each_member_gets_the_inputs_it_reads() -> None:
    torch.manual_seed(0)
    image = TactileClassifier(num_classes=4, num_touches=3).eval()
    cloud = ContactCloudClassifier(num_classes=4, num_touches=10, points_per_touch=4, width=16).eval()
    fused = LateFusionClassifier([image, cloud], "mean_log_prob")
    assert fused.touch_inputs == ("tactile", "patch_points", "patch_normals", "patch_mask")
    assert fused.num_touches == 3  # the paper's classifier takes at most its N
    x = _patch_inputs()
    with torch.no_grad():
        lp = fused.member_log_probs(*x)  # (M, B, C)
        torch.testing.assert_close(lp[0], F.log_softmax(image(x[0]), -1))
        torch.testing.assert_close(lp[1], F.log_softmax(cloud(*x), -1))
    assert not cloud.reads_images and ContactCloudClassifier(image_features=True, width=8).reads_images


def test_bad_fusions_are_refused() -> None:
    a = _Fixed([0.0, 1.0])
    with pytest.raises(ValueError, match="at least 2 classifiers"):
        LateFusionClassifier([a])
    with pytest.raises(ValueError, match="unknown fusion rule 'vote'"):
        LateFusionClassifier([a, a], rule="vote")
    with pytest.raises(ValueError, match=r"different numbers of classes: \[2, 3\]"):
        LateFusionClassifier([a, _Fixed([0.0, 1.0, 2.0])])(torch.zeros(1, 1, 3, 2, 2))
    with pytest.raises(ValueError, match=r"expected 1 inputs \['tactile'\], got 2"):
        LateFusionClassifier([a, a])(torch.zeros(1, 1, 3, 2, 2), torch.zeros(1))
