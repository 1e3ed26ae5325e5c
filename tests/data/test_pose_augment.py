"""Turning a touch set about the world's up axis."""

import math

import pytest
import torch

from tvrecon.data.pose_augment import turn_about_up


def test_quarter_turn_and_invariants() -> None:
    x = torch.tensor([[1.0, 0.0, 0.5], [0.0, 2.0, -1.0]])
    torch.testing.assert_close(turn_about_up(x, math.pi / 2), torch.tensor([[0.0, 1.0, 0.5], [-2.0, 0.0, -1.0]]))
    y = torch.randn(5, 7, 3)
    z = turn_about_up(y, 1.234)
    torch.testing.assert_close(z.norm(dim=-1), y.norm(dim=-1))  # lengths and heights kept
    torch.testing.assert_close(z[..., 2], y[..., 2])
    torch.testing.assert_close(turn_about_up(z, -1.234), y, atol=1e-6, rtol=1e-6)
    with pytest.raises(ValueError, match=r"vectors must have shape \(\.\.\., 3\), got \(4, 2\)"):
        turn_about_up(torch.zeros(4, 2), 0.1)
    with pytest.raises(ValueError, match="finite"):
        turn_about_up(y, float("nan"))
