"""The compiled step's fixed-step polar decomposition as one C++ loop (``compiled.polar.fused_polar``, eight particles
at a time until they converge) equals ``kernels.polar_fixed`` to float32 round-off, reports the same convergence
(too few steps, a singular or NaN F), and a compiled press on one thread takes it at every step."""

import pytest
import torch
from test_mpm_compile import _press, needs_compiler

from tvrecon.sim.mpm import MLSMPM, MPMConfig
from tvrecon.sim.mpm.compiled import polar, step
from tvrecon.sim.mpm.compiled.kernels import NEWTON_ITERS, polar_fixed

STOP = (8.0 * torch.finfo(torch.float32).eps) ** 0.5  # fused_step's tolerance


def _deformations(P: int, strain: float, seed: int = 0) -> torch.Tensor:
    """(9, P) channel-first F = Q S: random rotations times symmetric stretches of about ``strain``."""
    g = torch.Generator().manual_seed(seed)
    Q, _ = torch.linalg.qr(torch.randn(P, 3, 3, generator=g))
    S = torch.eye(3) + strain * torch.randn(P, 3, 3, generator=g)
    return (Q @ (0.5 * (S + S.transpose(1, 2)))).reshape(P, 9).T.contiguous()


@pytest.fixture
def built(one_thread):
    if not polar.polar_grid_available(torch.zeros(9, 1)):
        pytest.skip("the fused polar loop could not be built here")


@needs_compiler
@pytest.mark.parametrize("P", [1, 8, 203])  # a group of 8 padded with identities, whole groups, both
@pytest.mark.parametrize("strain", [0.0, 0.02, 0.1])
def test_fused_polar_equals_polar_fixed(built, P, strain):
    F = _deformations(P, strain)
    want, ok_want = polar_fixed(F, STOP, NEWTON_ITERS)
    got, ok_got = polar.fused_polar(F, STOP, NEWTON_ITERS)
    assert got.shape == (9, P) and bool(ok_got) is bool(ok_want) is True
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)
    R = got.T.reshape(P, 3, 3)
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3).expand(P, 3, 3), rtol=0, atol=1e-5)


@needs_compiler
def test_fused_polar_reports_what_did_not_converge(built):
    F = _deformations(20, 0.1)
    assert bool(polar_fixed(F, STOP, 1)[1]) is False
    assert bool(polar.fused_polar(F, STOP, 1)[1]) is False, "one step is not enough at 10% strain"
    singular = F.clone()
    singular[:, 13] = 0.0
    assert bool(polar.fused_polar(singular, STOP, NEWTON_ITERS)[1]) is False
    nan = F.clone()
    nan[4, 17] = float("nan")
    assert bool(polar.fused_polar(nan, STOP, NEWTON_ITERS)[1]) is False
    with pytest.raises(ValueError, match=r"\(9, P\) channel-first"):
        polar.fused_polar(F.T.contiguous(), STOP, NEWTON_ITERS)


@pytest.mark.slow
@needs_compiler
def test_compiled_press_takes_the_fused_polar(one_thread, monkeypatch):
    calls = []

    def counted(*args):  # noqa: ANN002, ANN202
        calls.append(args[0].shape[1])
        return polar.fused_polar(*args)

    monkeypatch.setattr(step, "fused_polar", counted)
    cfg = MPMConfig(n_grid=32)
    s_ref, f_ref = _press(MLSMPM(cfg), 30)
    s_new, f_new = _press(MLSMPM(cfg, compile=True), 30)
    assert len(calls) == 30, "the compiled steps must use the fused polar here"
    for name in ("x", "v", "F"):
        torch.testing.assert_close(getattr(s_new, name), getattr(s_ref, name), rtol=1e-5, atol=1e-6, msg=name)
    torch.testing.assert_close(f_new, f_ref, rtol=1e-5, atol=1e-8)
