"""Touch-set classifier: shapes, order invariance, masking and gradient flow (its tiny-batch overfit is in
test_classifier.py, beside the paper's classifier)."""

import pytest
import torch

from tvrecon.models.components.touch_set import TouchSetClassifier


def test_shapes_order_invariance_and_masking() -> None:
    torch.manual_seed(0)
    clf = TouchSetClassifier(num_classes=7, num_touches=4).eval()
    x = torch.rand(2, 4, 3, 32, 32)
    out = clf(x)
    assert out.shape == (2, 7)
    torch.testing.assert_close(clf(x[:, [2, 0, 3, 1]]), out, rtol=1e-5, atol=1e-5)  # a set: order is irrelevant
    # masked touches count as absent: the same as giving only the real ones, whatever the masked content
    mask = torch.tensor([[True, True, False, False], [True, False, False, False]])
    junk = x.clone()
    junk[~mask] = 100.0
    masked = clf(junk, mask)
    torch.testing.assert_close(masked[0], clf(x[:1, :2])[0], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(masked[1], clf(x[1:, :1])[0], rtol=1e-5, atol=1e-5)
    assert not torch.allclose(clf(x[:, :1]), out, atol=1e-4)  # more touches change the answer
    with pytest.raises(ValueError, match="at least one real touch"):
        clf(x, torch.zeros(2, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="dropout"):
        TouchSetClassifier(dropout=1.0)


def test_gradient_reaches_the_shared_trunk_from_every_touch() -> None:
    torch.manual_seed(0)
    clf = TouchSetClassifier(num_classes=3, num_touches=3)
    x = torch.rand(2, 3, 3, 16, 16, requires_grad=True)
    clf(x).logsumexp(1).sum().backward()
    assert clf.trunk.conv1.weight.grad is not None and clf.trunk.conv1.weight.grad.abs().sum() > 0
    assert (x.grad.abs().sum(dim=(2, 3, 4)) > 0).all()  # every touch of every sample contributes
