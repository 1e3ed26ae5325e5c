"""The fused C++ G2P gather of the compiled step on CPU (``compiled.gather.fused_g2p``) equals the inductor kernel's
function (``kernels.g2p_update``, run eagerly) to float32 round-off, refuses a stencil outside the block, and a
compiled press that uses it equals the eager step as the other compiled tests require. The weights the compiled
step computes from ``fx`` (``grid.bspline_weights``) are the eager stencil's table."""

import pytest
import torch
from test_mpm_compile import _press, needs_compiler

from tvrecon.sim.mpm import MLSMPM, MPMConfig, ParticleState
from tvrecon.sim.mpm.block_grid import Stencil, Transfer, block_dims, bspline_weights
from tvrecon.sim.mpm.compiled import gather, scatter, step
from tvrecon.sim.mpm.compiled.kernels import block_index, g2p_update, stencil_base


def _g2p_inputs(B: int, hand: str, seed: int = 0):
    """A block grid of B scenes with random node velocities and particles inside it, as fused_step hands them over."""
    g = torch.Generator().manual_seed(seed)
    P, inv_dx = 400 * B, 32.0
    x = 0.4 + 0.2 * torch.rand(P, 3, generator=g)
    base_t, fx, lo_f, hi_f = stencil_base(x.T.contiguous(), inv_dx, B)
    D = block_dims(lo_f.T, hi_f.T, B)  # as fused_step lays the blocks out
    lo = lo_f.to(torch.int64)
    lin = block_index(base_t, lo, torch.tensor([D[1], D[2], D[0] * D[1] * D[2]]))
    N, S0, S1 = B * D[0] * D[1] * D[2], D[1] * D[2], D[2]
    gv = torch.randn(N, 3, generator=g)
    Ft = (torch.eye(3) + 0.05 * torch.randn(P, 3, 3, generator=g)).reshape(P, 9).T.contiguous()
    alpha = torch.rand(P, generator=g) if hand != "none" else None
    hvt = {"none": None, "one": torch.randn(3, 1, generator=g), "each": torch.randn(3, P, generator=g)}[hand]
    return gv, lin, fx, x.T.contiguous(), Ft, alpha, hvt, S0, S1, 1e-3, inv_dx


@needs_compiler
@pytest.mark.parametrize("B", [1, 3])
@pytest.mark.parametrize("hand", ["none", "one", "each"])
def test_fused_g2p_matches_the_kernel_function(one_thread, B, hand):
    args = _g2p_inputs(B, hand)
    if not gather.g2p_grid_available(args[0], *args[2:5]):
        pytest.skip("the fused gather could not be built here")
    gv, lin, fx, xt, Ft, alpha, hvt, S0, S1, dt, inv_dx = args
    runs = gv.as_strided((gv.shape[0] - 2, 9), (3, 1))
    offs = torch.tensor([i * S0 + j * S1 for i in range(3) for j in range(3)])
    want = g2p_update(runs, offs, lin, fx, xt, Ft, alpha, hvt, dt, inv_dx)
    got = gather.fused_g2p(*args)
    for name, a, b in zip("xvCF", got, want, strict=True):
        assert a.shape == b.shape
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5 * float(b.abs().max()), msg=name)
    if hand == "none":  # no alpha: the grid's velocity, whatever the hand
        torch.testing.assert_close(got[1], want[1])


@needs_compiler
def test_fused_g2p_refuses_a_stencil_outside_the_block(one_thread):
    """A base node whose stencil leaves the block is an IndexError, never a read out of bounds."""
    gv, lin, *rest = _g2p_inputs(1, "one")
    if not gather.g2p_grid_available(gv):
        pytest.skip("the fused gather could not be built here")
    N = gv.shape[0]
    for bad in (N - 1, -1):
        broken = lin.clone()
        broken[7] = bad
        with pytest.raises(IndexError, match=f"1 of {lin.numel()} particles leave the {N}-node block"):
            gather.fused_g2p(gv, broken, *rest)


def test_weights_from_fx_are_the_eager_stencil_table():
    """``bspline_weights`` of the stencil's fx (what the compiled kernels and C++ transfers compute) equals the eager
    step's (27, P) table; ``Stencil.weights`` and ``Transfer.weights`` give it from fx when no table was kept."""
    g = torch.Generator().manual_seed(1)
    x = 0.3 + 0.4 * torch.rand(500, 3, generator=g)
    state = ParticleState.create(x, torch.zeros_like(x), volume=torch.full((500,), 1e-6), rho=1.0)
    st = MLSMPM(MPMConfig(n_grid=32))._stencil(state, 1)
    fxt = st.fx.T.contiguous()
    torch.testing.assert_close(torch.stack(bspline_weights(fxt), 0), st.w, rtol=0, atol=1e-7)
    lazy = Stencil(st.fx, None, st.lo, st.lin, st.D, st.n_nodes, st.chunk)
    cand = torch.tensor([3, 99, 250])
    torch.testing.assert_close(lazy.weights(cand), st.w[:, cand], rtol=0, atol=1e-7)
    assert torch.equal(st.weights(cand), st.w[:, cand])
    tr = Transfer(st.lin, None, torch.ones(st.n_nodes), torch.zeros(st.n_nodes, 3), (1, 1), fxt)
    torch.testing.assert_close(tr.weights(), st.w, rtol=0, atol=1e-7)
    with pytest.raises(ValueError, match="weights w or its stencil's fx"):
        Transfer(st.lin, None, torch.ones(1), torch.zeros(1, 3), (1, 1)).weights()


@pytest.mark.slow
@needs_compiler
def test_compiled_step_with_the_fused_loops_equals_eager(one_thread, monkeypatch):
    """A compiled press on one thread takes both C++ loops, the P2G scatter and the G2P gather (each counted), and
    stays within the compiled tolerances."""
    calls = {"fused_p2g": 0, "fused_g2p": 0}

    def counted(name, fn):  # noqa: ANN001, ANN202
        def run(*args):  # noqa: ANN002, ANN202
            calls[name] += 1
            return fn(*args)

        return run

    monkeypatch.setattr(step, "fused_p2g", counted("fused_p2g", scatter.fused_p2g))
    monkeypatch.setattr(step, "fused_g2p", counted("fused_g2p", gather.fused_g2p))
    cfg = MPMConfig(n_grid=32)
    s_ref, f_ref = _press(MLSMPM(cfg), 30)
    comp = MLSMPM(cfg, compile=True)
    s_new, f_new = _press(comp, 30)
    assert comp.compiled and calls["fused_p2g"] == 30, "the compiled steps must use the fused scatter here"
    assert calls["fused_g2p"] == 30, "the compiled steps must use the fused gather here"
    for name in ("x", "v", "F"):
        torch.testing.assert_close(getattr(s_new, name), getattr(s_ref, name), rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(f_new, f_ref, rtol=1e-5, atol=1e-8)
