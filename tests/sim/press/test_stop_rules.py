"""The cheap first stage of the terminal check decides only where the exact chamfer is below the threshold."""

from __future__ import annotations

import torch

from tvrecon.sim.press.stop_rules import (
    DisplacementRule,
    StopCheck,
    ThresholdRule,
    chamfer_reaches,
    chamfer_surely_below,
    rest_terms,
    terminal_chamfer,
    terminal_displacement,
)
from tvrecon.sim.sensor import SensorConfig, pad_lattice


def _layers(dtype: torch.dtype) -> tuple[torch.Tensor, tuple[int, int, float], list[torch.Tensor]]:
    """A 16x12 rest layer in cells (as the press builds it: domain units / dx, float32 rounding) and deformed ones."""
    cfg = SensorConfig(resolution=(16, 12), layers=2)
    dx = 1.0 / 128
    x0 = (pad_lattice(cfg)[:192] * dx + torch.tensor([0.5, 0.5, 0.51])) / dx
    g = torch.Generator().manual_seed(5)
    xs = []
    for scale in (0.005, 0.02, 0.05, 0.1, 0.2, 0.4):
        bump = scale * torch.randn(192, 3, generator=g, dtype=torch.float64)
        bump[:, 2] -= 3 * scale * (x0[:, 0] - x0[:, 0].mean()).double().abs() / 8  # a dent, not only noise
        xs.append((x0.double() + bump + torch.tensor([0.3, -0.2, -2.0], dtype=torch.float64)).to(dtype))
    return x0.to(dtype), (16, 12, float(cfg.spacing)), xs


def test_surely_below_only_below_the_chamfer() -> None:
    """True only when the exact chamfer is below the threshold, and True well below it (it must skip steps)."""
    for dtype in (torch.float32, torch.float64):
        x0, lattice, xs = _layers(dtype)
        rest = rest_terms(x0, lattice)
        assert 0 <= rest[1] < 1e-4  # float32 rounding of the rest layer only
        for x in xs:
            value = terminal_chamfer(x, x0, lattice)
            for f in (0.3, 0.6, 0.9, 0.999, 1.0, 1.001, 1.5, 2.5, 4.0):
                thr = f * value
                if chamfer_surely_below(x, rest, thr):
                    assert value < thr
                assert chamfer_reaches(x, x0, lattice, thr, rest=rest) == (value >= thr)
            assert chamfer_surely_below(x, rest, 4.0 * value)


def test_threshold_rule_memo_is_the_exact_chamfer() -> None:
    """When the rule computes the exact chamfer it leaves that value for the reading (the same call's result)."""

    class State:
        steps, travel, contact, force_hist = 10, 3.0, True, [1.0]

    x0, lattice, xs = _layers(torch.float32)
    x = xs[-1]
    value = terminal_chamfer(x, x0, lattice)
    rule = ThresholdRule(0.999 * value)
    check = StopCheck(x, x0, lattice)
    assert rule.reached(State(), check)
    assert check.memo["chamfer"] == value
    far = StopCheck(x, x0, lattice)
    assert not ThresholdRule(10.0 * value).reached(State(), far)
    assert "chamfer" not in far.memo  # decided by the bound: no exact value computed


def test_chamfer_is_blind_to_in_plane_motion_beyond_half_a_spacing() -> None:
    """Eq. 12 matches nearest neighbours, not particles: at most 2 mean |u - mean u|^2, equal to it for a dent, and
    saturated by a lateral (Poisson) spread once the edge particles move over half the lattice spacing.

    This is why the default stop on a face larger than the pad comes deeper on finer grids (the spread is one
    physical length, the spacing half a cell; ``bench_stop_measure.py``, ``docs/validation/physics.md``)."""
    x0, lattice, _ = _layers(torch.float64)
    H, W, sp = lattice
    rel = x0 - x0.mean(0)

    def displacement(x: torch.Tensor) -> float:
        u = (x - x.mean(0)) - rel
        return 2 * float((u**2).sum(1).mean())

    dent = x0.clone()
    dent[:, 2] -= 0.3 * torch.exp(-(rel[:, :2] ** 2).sum(1) / 8)  # a normal dent, 0.3 cells deep
    assert abs(terminal_chamfer(dent, x0, lattice) - displacement(dent)) < 1e-9 * displacement(dent)
    ratios = []
    for strain in (0.01, 0.03, 0.1, 0.2):  # edge particles move 0.04 .. 0.75 spacings
        spread = x0.clone()
        spread[:, :2] = x0.mean(0)[:2] + rel[:, :2] * (1 + strain)
        edge = float(strain * rel[:, :2].abs().max() / sp)
        ratio = terminal_chamfer(spread, x0, lattice) / displacement(spread)
        assert ratio <= 1 + 1e-9
        if edge < 0.5:
            assert ratio > 0.999, (strain, edge, ratio)
        ratios.append(ratio)
    assert ratios[-1] < 0.6 * ratios[0]  # beyond half a spacing the chamfer no longer grows with the spread


def test_displacement_measure_bounds_the_chamfer_and_sees_the_spread() -> None:
    """``terminal_displacement`` >= the chamfer on every layer, and a rule on it stops where eq. 12 saturates."""

    class State:
        steps, travel, contact, force_hist = 10, 3.0, True, [1.0]

    x0, lattice, xs = _layers(torch.float64)
    for x in xs:
        assert terminal_displacement(x, x0) >= terminal_chamfer(x, x0, lattice) * (1 - 1e-9)
    rel = x0 - x0.mean(0)
    spread = x0.clone()
    spread[:, :2] = x0.mean(0)[:2] + rel[:, :2] * 1.2  # edge particles 1.5 spacings out
    value = terminal_displacement(spread, x0)
    assert terminal_chamfer(spread, x0, lattice) < 0.5 * value
    assert DisplacementRule(0.9 * value).reached(State(), StopCheck(spread, x0, lattice))
    assert not ThresholdRule(0.9 * value).reached(State(), StopCheck(spread, x0, lattice))
