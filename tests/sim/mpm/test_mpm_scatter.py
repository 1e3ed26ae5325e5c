"""The fused C++ P2G scatter of the compiled step on CPU (``mpm_scatter.fused_p2g``) equals the row path
(``p2g_contrib`` rows, ``index_add_``, ``node_sums``) to float32 round-off (a compiled press through it and the C++
G2P: ``test_mpm_gather.py``)."""

import pytest
import torch
from test_mpm_compile import needs_compiler

from tvrecon.sim.mpm.block_grid import block_layout
from tvrecon.sim.mpm.compiled import scatter as mpm_scatter
from tvrecon.sim.mpm.compiled.kernels import node_sums, p2g_contrib, polar_fixed, stencil_base


@needs_compiler
@pytest.mark.parametrize("B", [1, 2])
def test_fused_p2g_matches_row_scatter(one_thread, B):
    g = torch.Generator().manual_seed(0)
    P, n_grid = 300 * B, 32
    x = 0.4 + 0.2 * torch.rand(P, 3, generator=g)
    F = torch.eye(3) + 0.05 * torch.randn(P, 3, 3, generator=g)
    C = torch.randn(P, 3, 3, generator=g)
    v = torch.randn(P, 3, generator=g)
    m, vol = 0.5 + torch.rand(P, generator=g), 0.5 + torch.rand(P, generator=g)
    batch = torch.arange(B).repeat_interleave(P // B) if B > 1 else None
    if not mpm_scatter.p2g_grid_available(x):
        pytest.skip("the fused scatter could not be built here")
    inv_dx, dx, dt, mu, lam = float(n_grid), 1.0 / n_grid, 1e-3, 1.2, 0.8
    base_t, fx, _, _ = stencil_base(x.T.contiguous(), inv_dx)
    lo, lin, D = block_layout(base_t.T, batch, B, P // B if B > 1 else None)
    N, S0, S1 = B * D[0] * D[1] * D[2], D[1] * D[2], D[2]
    Ft, Ct, vt = F.reshape(P, 9).T.contiguous(), C.reshape(P, 9).T.contiguous(), v.T.contiguous()
    Rt, ok = polar_fixed(Ft, (8.0 * torch.finfo(torch.float32).eps) ** 0.5)
    assert bool(ok)
    rows = p2g_contrib(Ft, Rt, Ct, vt, fx, m, vol, 0, P, mu, lam, dt, dx, inv_dx)
    ref = node_sums(torch.zeros(N, 108).index_add_(0, lin, rows), S0, S1)  # (4, N)
    got = mpm_scatter.fused_p2g(Ft, Rt, Ct, vt, fx, m, vol, lin, N, S0, S1, mu, lam, dt, dx, inv_dx)  # (N, 4)
    assert ref.abs().max() > 0
    torch.testing.assert_close(got.T, ref, rtol=1e-5, atol=1e-6 * float(ref.abs().max()))


@needs_compiler
def test_fused_p2g_refuses_a_stencil_outside_the_block(one_thread):
    """A base node whose 3x3x3 stencil leaves the block is an IndexError (as the row path's index_add_), never a
    write out of bounds."""
    P, N, S0, S1 = 4, 5 * 5 * 5, 25, 5
    if not mpm_scatter.p2g_grid_available(torch.zeros(1)):
        pytest.skip("the fused scatter could not be built here")
    F = torch.eye(3).reshape(9, 1).repeat(1, P)
    args = (F, F, torch.zeros(9, P), torch.zeros(3, P), torch.full((3, P), 0.5))  # weights 0.5, 0.5, 0 per axis
    m = torch.ones(P)
    ok = torch.tensor([0, 1, 31, 62])  # the last one's stencil ends at node 62 + 2 * 25 + 2 * 5 + 2 = 124
    grid = mpm_scatter.fused_p2g(*args, m, m, ok, N, S0, S1, 1.0, 1.0, 1e-3, 0.1, 10.0)
    assert float(grid[:, 0].sum()) == pytest.approx(P)  # each particle's weights sum to 1: its mass lands whole
    for bad in (63, -1):
        with pytest.raises(IndexError, match="1 of 4 particles leave the 125-node block"):
            mpm_scatter.fused_p2g(*args, m, m, torch.tensor([0, 1, 31, bad]), N, S0, S1, 1.0, 1.0, 1e-3, 0.1, 10.0)
