"""N-touch tactile classifiers: shapes, padding/masking and overfitting a tiny batch."""

import pytest
import torch

from tvrecon.models.components.classifier import TactileClassifier
from tvrecon.models.components.touch_set import TouchSetClassifier


def test_shapes_padding_and_masking() -> None:
    clf = TactileClassifier(num_classes=7, num_touches=4).eval()
    assert clf.net.conv1.in_channels == 12
    x = torch.rand(2, 4, 3, 32, 32)
    assert clf(x).shape == (2, 7)
    # fewer touches are zero padded; masked touches are zeroed
    two = clf(x[:, :2])
    masked = clf(x, torch.tensor([[True, True, False, False]] * 2))
    assert torch.allclose(two, masked, atol=1e-5)
    assert not torch.allclose(two, clf(x), atol=1e-5)


@pytest.mark.parametrize("model", [TactileClassifier, TouchSetClassifier])
def test_bad_input_raises(model: type) -> None:
    clf = model(num_classes=7, num_touches=4).eval()
    x = torch.rand(2, 4, 3, 32, 32)
    with pytest.raises(ValueError, match="num_touches"):
        clf(torch.rand(1, 5, 3, 32, 32))
    with pytest.raises(ValueError, match=r"\(B, N, 3, h, w\)"):
        clf(torch.rand(1, 4, 32, 32))
    with pytest.raises(ValueError, match=r"touch_mask must have shape \(B, N\)"):
        clf(x, torch.ones(2, 3, dtype=torch.bool))


@pytest.mark.slow
@pytest.mark.parametrize("model", [TactileClassifier, TouchSetClassifier])
def test_overfits_tiny_batch(model: type) -> None:
    """The paper's stacked classifier and the touch-set classifier (tvrecon.models.components.touch_set) both fit 8
    samples."""
    torch.manual_seed(0)
    clf = model(num_classes=4, num_touches=2)
    x = torch.rand(8, 2, 3, 16, 16)
    y = torch.tensor([0, 1, 2, 3, 0, 1, 2, 3])
    opt = torch.optim.Adam(clf.parameters(), lr=1e-3)
    for _ in range(40):
        loss = torch.nn.functional.cross_entropy(clf(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():  # train-mode batch norm
        acc = (clf(x).argmax(1) == y).float().mean().item()
    assert acc == 1.0, f"train accuracy {acc}"
