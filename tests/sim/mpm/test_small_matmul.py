"""``matmul3``: per-particle 3x3 products equal ``torch.matmul`` on every device; the broadcast form (the CUDA path)
is checked on the CPU too, values and gradients."""

from __future__ import annotations

import pytest
import torch

from tvrecon.sim.mpm.small_matmul import matmul3


@pytest.mark.parametrize("k", [1, 3])
def test_matmul3_equals_matmul(k: int) -> None:
    g = torch.Generator().manual_seed(0)
    a = torch.randn(1000, 3, 3, generator=g, dtype=torch.float64)
    b = torch.randn(1000, 3, k, generator=g, dtype=torch.float64)
    torch.testing.assert_close(matmul3(a, b), a @ b, rtol=0, atol=0)  # the CPU runs matmul itself
    torch.testing.assert_close(matmul3(a, b, broadcast=True), a @ b, rtol=1e-12, atol=1e-12)  # the CUDA form
    at = a.clone().requires_grad_()
    matmul3(at, b, broadcast=True).square().sum().backward()
    torch.testing.assert_close(at.grad, 2 * (a @ b) @ b.transpose(1, 2), rtol=1e-12, atol=1e-12)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_matmul3_cuda_and_gradients() -> None:
    a = torch.randn(70_000, 3, 3, device="cuda", requires_grad=True)
    b = torch.randn(70_000, 3, 3, device="cuda", requires_grad=True)
    out = matmul3(a, b.transpose(1, 2))
    torch.testing.assert_close(out, a @ b.transpose(1, 2), rtol=1e-5, atol=1e-5)
    out.square().sum().backward()
    assert a.grad is not None and b.grad is not None
