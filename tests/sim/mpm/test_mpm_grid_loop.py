"""The compiled step's grid update as one C++ loop (``compiled.grid_loop.fused_grid_collide``) equals the inductor
kernel ``compiled.grid.grid_collide`` on the fused P2G's (N, 4) sums to float32 round-off (with and without
colliders, friction and damping, several scenes), keeps a NaN visible to the speed check, and a compiled press on one
thread takes it at every step."""

import math

import pytest
import torch
from test_mpm_compile import _press, needs_compiler

from tvrecon.sim.mpm import MLSMPM, MPMConfig
from tvrecon.sim.mpm.compiled import grid_loop, step
from tvrecon.sim.mpm.compiled.grid import grid_collide


@pytest.fixture
def built(one_thread):
    if not grid_loop.grid_loop_available(torch.zeros(1, 4)):
        pytest.skip("the grid loop could not be built here")


def _grid(N: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(N, 4) sums [m, m v] (a third of the nodes empty), sdf (N,) about half inside, unit normals (3, N)."""
    g = torch.Generator().manual_seed(seed)
    m = torch.rand(N, generator=g) * (torch.rand(N, generator=g) > 0.33)
    G = torch.cat([m[:, None], m[:, None] * torch.randn(N, 3, generator=g)], 1).contiguous()
    sdf = torch.randn(N, generator=g)
    nrm = torch.nn.functional.normalize(torch.randn(3, N, generator=g), dim=0).contiguous()
    return G, sdf, nrm


@needs_compiler
@pytest.mark.parametrize("B", [1, 3])
@pytest.mark.parametrize(("friction", "damp"), [(0.0, 1.0), (0.4, 1.0), (0.0, 0.97)])
@pytest.mark.parametrize("colliders", [True, False])
def test_fused_grid_collide_equals_the_kernel(built, B, friction, damp, colliders):
    G, sdf, nrm = _grid(600 * B)
    if not colliders:
        sdf = nrm = None
    want = grid_collide(G, 1, 1, sdf, nrm, B, 1e-3, friction, damp)  # S0, S1 unused on (N, 4) sums
    got = grid_loop.fused_grid_collide(G, sdf, nrm, B, 1e-3, friction, damp)
    for name, g, w in zip(("gv", "gm", "node_force", "force", "vmax"), got, want, strict=True):
        assert g.shape == w.shape, name
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-5, msg=name)
    if colliders:
        assert (got[2].abs().sum(1) > 0).sum() > 50  # the projection acted on many nodes: a real comparison


@needs_compiler
def test_a_nan_node_reaches_the_speed_check(built):
    G, sdf, nrm = _grid(300)
    G[123, 2] = math.nan
    assert math.isnan(float(grid_loop.fused_grid_collide(G, sdf, nrm, 1, 1e-3, 0.0, 1.0)[4]))
    assert math.isnan(float(grid_collide(G, 1, 1, sdf, nrm, 1, 1e-3, 0.0, 1.0)[4]))  # the kernel does the same
    assert not grid_loop.grid_loop_available(torch.zeros(5, 108))  # the inductor P2G's rows keep the kernel
    with pytest.raises(ValueError, match="scenes of equal size"):
        grid_loop.fused_grid_collide(G[:299], None, None, 2, 1e-3, 0.0, 1.0)


@pytest.mark.slow
@needs_compiler
def test_compiled_press_takes_the_grid_loop(built, monkeypatch):
    calls = []

    def counted(*args):  # noqa: ANN002, ANN202
        calls.append(args[0].shape[0])
        return grid_loop.fused_grid_collide(*args)

    monkeypatch.setattr(step, "fused_grid_collide", counted)
    cfg = MPMConfig(n_grid=32, friction=0.3)
    s_ref, f_ref = _press(MLSMPM(cfg), 25, batched=True)
    s_new, f_new = _press(MLSMPM(cfg, compile=True), 25, batched=True)
    assert len(calls) == 25, "the compiled steps must use the grid loop here"
    for name in ("x", "v", "F"):
        torch.testing.assert_close(getattr(s_new, name), getattr(s_ref, name), rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(f_new, f_ref, rtol=1e-5, atol=1e-8)
