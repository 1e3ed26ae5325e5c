"""Products of per-particle 3x3 matrices, ``A_p @ B_p`` for millions of particles p, in the kernel each device runs
fastest.

On the CPU ``torch.matmul``'s batched kernel is the fast one. On CUDA it calls cuBLAS batched GEMM, which splits a
batch over 65,535 matrices into one launch per 65,535 (37 launches for the 2.4 M particles of 64 paper touches), each
a 32 x 32 tile for a 3 x 3 product: on an H100 the three per-particle products of a step took 42% of a batch-64 press
step's GPU time (``benchmarks/speed/bench_gpu.py --profile 64``, ``benchmarks/README.md``). There the product is
written as a broadcast multiply summed over the inner axis: one elementwise kernel and one reduction, memory-bound.
"""

from __future__ import annotations

from torch import Tensor

__all__ = ["matmul3"]


def matmul3(a: Tensor, b: Tensor, broadcast: bool | None = None) -> Tensor:
    """Batched ``a @ b`` of small matrices.

    Args:
        a: (P, 3, 3) float tensor.
        b: (P, 3, k) float tensor (k = 1 for matrix-vector products), same dtype and device.
        broadcast: the broadcast form (True) or ``torch.matmul`` (False); None: the broadcast form on CUDA only.

    Returns:
        (P, 3, k): ``a[p] @ b[p]`` for every p (equal to ``torch.matmul`` up to float round-off in the summation order).
    """
    if not (a.device.type == "cuda" if broadcast is None else broadcast):
        return a.matmul(b)
    return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)  # (P, 3, 3, k) products, summed over the inner index
