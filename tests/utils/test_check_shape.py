import numpy as np
import pytest
import torch

from tvrecon.utils.shape_check import check_shape


def test_check_shape_accepts_documented_shapes() -> None:
    check_shape(torch.zeros(2, 5, 3), "(B, N, 3)", "x")
    check_shape(np.zeros((4, 3)), "(N, 3)", "points")
    check_shape(torch.zeros(3), "(3,)", "direction")
    check_shape(torch.zeros(7, 2, 3, 8, 8), "(..., 3, H, W)", "images")
    check_shape(torch.zeros(3, 8, 8), "(..., 3, H, W)", "images")


@pytest.mark.parametrize(
    ("x", "spec", "message"),
    [
        (torch.zeros(2, 5, 4), "(B, N, 3)", r"x must have shape \(B, N, 3\), got \(2, 5, 4\)"),
        (torch.zeros(5, 3), "(B, N, 3)", r"x must have shape \(B, N, 3\), got \(5, 3\)"),
        (torch.zeros(8, 8), "(..., 3, H, W)", r"x must have shape \(\.\.\., 3, H, W\), got \(8, 8\)"),
    ],
)
def test_check_shape_names_the_input_and_both_shapes(x, spec: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_shape(x, spec, "x")


def test_check_shape_takes_documented_alternatives() -> None:
    check_shape(torch.zeros(2, 5, 3), "(B, V, 3) or (V, 3)", "verts")
    check_shape(torch.zeros(5, 3), "(B, V, 3) or (V, 3)", "verts")
    with pytest.raises(ValueError, match=r"verts must have shape \(B, V, 3\) or \(V, 3\), got \(5, 2\)"):
        check_shape(torch.zeros(5, 2), "(B, V, 3) or (V, 3)", "verts")
    with pytest.raises(ValueError, match=r"verts must have shape \(B, V, 3\) or \(V, 3\), got \(1, 2, 5, 3\)"):
        check_shape(torch.zeros(1, 2, 5, 3), "(B, V, 3) or (V, 3)", "verts")
