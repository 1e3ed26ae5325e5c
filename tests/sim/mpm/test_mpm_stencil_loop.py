"""The compiled step's stencil bases and block index as two C++ loops (``compiled.stencil``) are bit-identical to the
inductor kernels ``kernels.stencil_base`` / ``kernels.block_index``, keep a diverged (NaN) state visible to the block
check, and a compiled press on one thread calls neither kernel through dynamo."""

import math

import pytest
import torch
from test_mpm_compile import _press, needs_compiler

from tvrecon.sim.mpm import MLSMPM, MPMConfig
from tvrecon.sim.mpm.compiled import stencil, step
from tvrecon.sim.mpm.compiled.kernels import block_index, stencil_base


@pytest.fixture
def built(one_thread):
    if not stencil.stencil_loops_available(torch.zeros(3, 1)):
        pytest.skip("the stencil loops could not be built here")


def _positions(P: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (0.3 + 0.4 * torch.rand(3, P, generator=g)).contiguous()


@needs_compiler
@pytest.mark.parametrize(("P", "B"), [(1, 1), (1000, 1), (1200, 4)])
@pytest.mark.parametrize("inv_dx", [40.0, 128.0])
def test_stencil_and_index_loops_equal_the_kernels_bit_for_bit(built, P, B, inv_dx):
    x = _positions(P)
    got, want = stencil.fused_stencil_base(x, inv_dx, B), stencil_base(x, inv_dx, B)
    for name, g, w in zip(("base", "fx", "lo", "hi"), got, want, strict=True):
        assert g.shape == w.shape and torch.equal(g, w), name
    lo = want[2].to(torch.int64)
    D = ((want[3] - want[2]).amax(1) + 3).to(torch.int64).tolist()
    dims = torch.tensor([D[1], D[2], D[0] * D[1] * D[2]])
    assert torch.equal(stencil.fused_block_index(want[0], lo, D), block_index(want[0], lo, dims))


@needs_compiler
def test_a_non_finite_position_stays_visible(built):
    x = _positions(800)
    x[1, 250] = math.nan  # scene 1 of 4
    x[2, 700] = math.inf  # scene 3
    base, _, lo, hi = stencil.fused_stencil_base(x, 64.0, 4)
    assert math.isnan(lo[1, 1]) and math.isnan(hi[1, 1]) and torch.isfinite(lo[:, [0, 2]]).all()
    assert math.isinf(hi[2, 3]) and hi[2, 3] > 0  # as amax: the block check raises on it
    lin = stencil.fused_block_index(base, torch.zeros(3, 4, dtype=torch.int64), [40, 40, 40])
    assert lin[250] == -1 and lin[700] == -1 and (lin[:250] >= 0).all()  # P2G's range check reports them
    with pytest.raises(ValueError, match="scenes of equal size"):
        stencil.fused_stencil_base(x[:, :799], 64.0, 4)


@pytest.mark.slow
@needs_compiler
def test_a_compiled_press_on_one_thread_calls_no_stencil_or_index_kernel(built, monkeypatch):
    names, loops = [], []
    call = step.CompiledKernels.__call__

    def counted(self, name, *args):  # noqa: ANN001, ANN002, ANN202
        names.append(name)
        return call(self, name, *args)

    def stencil_loop(*args):  # noqa: ANN002, ANN202
        loops.append(args[0].shape[1])
        return stencil.fused_stencil_base(*args)

    monkeypatch.setattr(step.CompiledKernels, "__call__", counted)
    monkeypatch.setattr(step, "fused_stencil_base", stencil_loop)
    cfg = MPMConfig(n_grid=32)
    s_ref, f_ref = _press(MLSMPM(cfg), 20, batched=True)
    s_new, f_new = _press(MLSMPM(cfg, compile=True), 20, batched=True)
    assert len(loops) == 20, "every compiled step must take the stencil loop here"
    assert "stencil" not in names and "index" not in names  # with the grid loop too: no kernel call at all
    for name in ("x", "v", "F"):
        torch.testing.assert_close(getattr(s_new, name), getattr(s_ref, name), rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(f_new, f_ref, rtol=1e-5, atol=1e-8)
