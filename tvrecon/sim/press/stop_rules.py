"""When a press stops: the terminal check of Algorithm 1 and the other stop rules, as an ordered list.

After every press step the rules of :func:`stop_rules` are asked in order; the first that answers True ends the
press (later rules are not evaluated: the terminal chamfer is the costly one)::

    1. TravelLimit     always: the hand travelled gap + max_depth cells, or max_steps steps
    2. DepthRule       ``depth``: indentation past first contact, cells              \\
       ForceRule       ``force``: mean normal contact force over the last 3 steps     > only the first one configured
       ThresholdRule   ``threshold``: terminal chamfer (paper eq. 12), after contact  /  is in the list
       (DisplacementRule in its place with ``PressConfig.terminal="displacement"``: beyond the paper)

The terminal threshold is in squared cells of the press's own grid, or, with ``PressConfig.threshold_grid`` = N, in
squared cells of an N-cell grid (a physical unit: :func:`threshold_cells` converts it). It is compared with the
paper's chamfer, or with ``PressConfig.terminal="displacement"`` (:class:`DisplacementRule`) with
:func:`terminal_displacement`, the same deformation matched particle to particle (beyond the paper: eq. 12's nearest
neighbours stop seeing a sideways spread past half a lattice spacing: docs/notes/stop-depth.md).

A ``depth`` rule needs travel: :func:`travel_for_depth` raises ``max_depth`` to ``depth + 0.5`` cells when it is
shorter, so the travel limit does not stop the press before the requested depth (the placement's collider region
and reach follow the raised value).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from tvrecon.sim.press.config import PressConfig

#: Travel (cells) a ``depth`` rule gets beyond the requested depth when it raises ``max_depth``.
DEPTH_TRAVEL_MARGIN = 0.5

#: Tolerance (cells) of the travel and depth comparisons (the travel is a sum of float steps).
_EPS_CELLS = 1e-6


def terminal_chamfer(x: Tensor, x0: Tensor, lattice: tuple[int, int, float] | None = None) -> float:
    """Terminal check of Algorithm 1, paper eq. 12 (eq:chamfer): the centred contact layer now vs at rest.

    ``l = mean_p min_q |x^_p - x^0_q|^2 + mean_q min_p |x^_p - x^0_q|^2`` with ``x^ = x - mean(x)``; the paper sums,
    we average (divide by |S|) so the threshold does not depend on the tactile resolution. Not differentiable
    (it only drives the terminal check).

    Args:
        x: (N, 3) contact layer now, in cells. x0: (N, 3) at rest, in cells.
        lattice: (H, W, spacing) when ``x0`` is the planar rest lattice of :func:`pad_lattice` (z constant); the
            first term is then exact by rounding to the lattice instead of a k-d tree query.
    Returns:
        the chamfer value in squared cells.
    """
    a_t = (x - x.mean(0)).detach()
    b = (x0 - x0.mean(0)).detach().cpu().double().numpy()
    a = a_t.cpu().double().numpy()
    if lattice is not None:
        H, W, sp = lattice
        j = np.clip(np.rint(a[:, 0] / sp + (W - 1) / 2), 0, W - 1)
        i = np.clip(np.rint(a[:, 1] / sp + (H - 1) / 2), 0, H - 1)
        d_ab2 = (a[:, 0] - (j - (W - 1) / 2) * sp) ** 2 + (a[:, 1] - (i - (H - 1) / 2) * sp) ** 2 + a[:, 2] ** 2
    else:
        d_ab, _ = cKDTree(b).query(a, workers=1)
        d_ab2 = d_ab**2
    d_ba, _ = cKDTree(a).query(b, workers=1)
    return float(d_ab2.mean() + (d_ba**2).mean())


def terminal_displacement(x: Tensor, x0: Tensor) -> float:
    """The deformation eq. 12 measures, with each particle matched to its own rest position (not the paper's).

    ``l = 2 mean_p |x^_p - x^0_p|^2`` with ``x^ = x - mean(x)``: at least :func:`terminal_chamfer` (each of its two
    terms is at most ``mean_p |x^_p - x^0_p|^2``) and equal to it while no particle moves sideways by more than half
    the lattice spacing; unlike the chamfer it keeps growing with a sideways (Poisson) spread, so one threshold is
    one deformation at every n_grid. Not differentiable (it only drives the terminal check).

    Args:
        x: (N, 3) contact layer now, in cells. x0: (N, 3) the same particles at rest, in cells.
    Returns:
        the measure in squared cells.
    """
    a, b = x.detach().double(), x0.detach().double()
    u = (a - a.mean(0)) - (b - b.mean(0))
    return float(2 * (u * u).sum(1).mean())


def rest_terms(x0: Tensor, lattice: tuple[int, int, float]) -> tuple[Tensor, float]:
    """What :func:`chamfer_surely_below` needs of the rest layer, once per press.

    Args:
        x0: (N, 3) planar rest lattice, in cells. lattice: (H, W, spacing) of ``x0``.
    Returns:
        ``b``: (N, 3) float64, ``x0`` centred as :func:`terminal_chamfer` centres it (float32 ops, then float64), and
        ``beta``: the root mean square distance of ``b`` to the nearest points of the ideal lattice (cells), the
        float32 rounding of the rest layer (~1e-5 cells).
    """
    b = (x0 - x0.mean(0)).detach().double()
    H, W, sp = lattice
    j = torch.clamp(torch.round(b[:, 0] / sp + (W - 1) / 2), 0, W - 1)
    i = torch.clamp(torch.round(b[:, 1] / sp + (H - 1) / 2), 0, H - 1)
    d2 = (b[:, 0] - (j - (W - 1) / 2) * sp) ** 2 + (b[:, 1] - (i - (H - 1) / 2) * sp) ** 2 + b[:, 2] ** 2
    return b, float(d2.mean().sqrt())


def rest_sq_sums(x: Tensor, rest: tuple[Tensor, float]) -> Tensor:
    """``sum_p |a_p - b_p|^2`` of :func:`chamfer_surely_below` for a batch of contact layers at once.

    Args:
        x: (B, N, 3) contact layers, in cells. rest: :func:`rest_terms` of their common rest layer.
    Returns:
        (B,) float64 sums (on ``x.device``), for ``StopCheck.memo["rest_sq_sum"]``: the press loop reads them with its
        one host read per step instead of one read per touch.
    """
    b, _ = rest
    a = (x - x.mean(1, keepdim=True)).detach().double()
    e = a - b.to(a.device)
    return (e * e).sum((1, 2))


def chamfer_surely_below(x: Tensor, rest: tuple[Tensor, float], threshold: float, sq_sum: float | None = None) -> bool:
    """True only when ``terminal_chamfer(x, x0, lattice) < threshold`` (False: undecided), with a few ops.

    With ``a`` and ``b`` the centred layers :func:`terminal_chamfer` builds and ``r`` the root mean square of ``|a_p -
    b_p|`` (each particle and its own rest point): the second chamfer term is at most ``r^2`` (each rest point has
    its own particle), and the first at most ``(r + beta)^2`` (each particle has the lattice point nearest its rest
    point, ``beta`` away from it in the mean square: triangle inequality of the root mean square). ``r`` is computed
    in float64 from the same float32 ``a`` and ``b`` (their differences are exact in float64, or rounded at 2^-53),
    so the relative 1e-6 margin covers the rounding of the sums with room to spare.

    Args:
        x: (N, 3) contact layer now, in cells. rest: :func:`rest_terms` of the rest layer. threshold: squared cells.
        sq_sum: ``sum_p |a_p - b_p|^2`` when the caller computed it (:func:`rest_sq_sums`), else computed here. It only
            decides whether this shortcut answers: a value off by round-off can only send the caller to the exact
            test, which gives the same answer.
    """
    b, beta = rest
    if sq_sum is None:
        a = (x - x.mean(0)).detach().double()
        e = a - b.to(a.device)
        sq_sum = float((e * e).sum())
    r = (sq_sum / len(x)) ** 0.5
    return (r + beta) ** 2 + r * r < float(threshold) * (1.0 - 1e-6)


def chamfer_reaches(
    x: Tensor,
    x0: Tensor,
    lattice: tuple[int, int, float],
    threshold: float,
    rest: tuple[Tensor, float] | None = None,
    memo: dict[str, float] | None = None,
) -> bool:
    """Whether ``terminal_chamfer(x, x0, lattice) >= threshold``, usually without a k-d tree.

    First :func:`chamfer_surely_below` (a handful of ops: most press steps end there). Then the exact first term plus
    a bound of the second: the second chamfer term (rest lattice -> nearest particle) is at most the mean squared
    distance of each rest point to *its own* particle (same index, both centred), so when the exact first term plus
    that bound stays below the threshold the answer is False; only otherwise is the exact value computed. Same result
    as comparing :func:`terminal_chamfer`, at a fraction of the cost per step.

    Args:
        x: (N, 3) contact layer now, in cells. x0: (N, 3) planar rest lattice, in cells.
        lattice: (H, W, spacing) of ``x0``. threshold: squared cells per particle.
        rest: :func:`rest_terms` of ``x0`` when the caller keeps them (computed here otherwise).
        memo: when given, the exact :func:`terminal_chamfer` value goes to ``memo["chamfer"]`` if it was computed.
    """
    sq_sum = None if memo is None else memo.get("rest_sq_sum")
    if chamfer_surely_below(x, rest_terms(x0, lattice) if rest is None else rest, threshold, sq_sum):
        return False
    a = (x - x.mean(0)).detach()
    b = (x0 - x0.mean(0)).detach().to(a)
    H, W, sp = lattice
    j = torch.clamp(torch.round(a[:, 0] / sp + (W - 1) / 2), 0, W - 1)
    i = torch.clamp(torch.round(a[:, 1] / sp + (H - 1) / 2), 0, H - 1)
    d_ab2 = (a[:, 0] - (j - (W - 1) / 2) * sp) ** 2 + (a[:, 1] - (i - (H - 1) / 2) * sp) ** 2 + a[:, 2] ** 2
    upper = float(d_ab2.mean() + ((a - b) ** 2).sum(1).mean())
    if upper < float(threshold) * (1.0 - 1e-6):
        return False
    value = terminal_chamfer(x, x0, lattice)
    if memo is not None:
        memo["chamfer"] = value
    return value >= float(threshold)


def travel_for_depth(p: PressConfig) -> PressConfig:
    """``p`` with ``max_depth`` raised to ``depth + DEPTH_TRAVEL_MARGIN`` when a ``depth`` rule needs more travel.

    Without it a ``depth`` above ``max_depth`` could never be reached (the travel limit stops first). The raised
    value also sizes the collider region and the reach of the placement. ``p`` itself is not changed.
    """
    if p.depth is not None and float(p.depth) + DEPTH_TRAVEL_MARGIN > float(p.max_depth):
        return dataclasses.replace(p, max_depth=float(p.depth) + DEPTH_TRAVEL_MARGIN)
    return p


class PressState(Protocol):
    """What the rules read of a touch being pressed (:class:`tvrecon.sim.press.loop.TouchRun`)."""

    steps: int
    travel: float
    contact: bool
    force_hist: list[float]


@dataclass(frozen=True)
class StopCheck:
    """The contact layer after a step, for rules that look at the pad (cells; ``lattice`` = (H, W, spacing)).

    ``memo``: values a rule computed on the way that the caller may reuse (``"chamfer"``: the exact
    :func:`terminal_chamfer` of this layer, when :class:`ThresholdRule` needed it), and values the caller computed
    for the rules (``"rest_sq_sum"``: :func:`rest_sq_sums` of this layer).
    """

    contact_cells: Tensor
    rest_cells: Tensor
    lattice: tuple[int, int, float]
    memo: dict[str, float] = field(default_factory=dict, compare=False, repr=False)


class StopRule(Protocol):
    """One stop rule: ``reached(state, check)`` is True when the press should stop after this step."""

    def reached(self, state: PressState, check: StopCheck) -> bool: ...


@dataclass(frozen=True)
class TravelLimit:
    """The hand never travels more than ``gap + max_depth`` cells nor presses more than ``max_steps`` steps."""

    max_steps: int
    max_travel: float  # gap + max_depth, cells

    def reached(self, state: PressState, check: StopCheck) -> bool:
        return state.steps >= self.max_steps or state.travel >= self.max_travel - _EPS_CELLS


@dataclass(frozen=True)
class DepthRule:
    """Stop at ``depth`` cells of hand travel past the start gap (the indentation past first contact)."""

    gap: float
    depth: float

    def reached(self, state: PressState, check: StopCheck) -> bool:
        return state.travel - self.gap >= self.depth - _EPS_CELLS


@dataclass(frozen=True)
class ForceRule:
    """Stop when the normal contact force, averaged over the last ``window`` steps, reaches ``force``."""

    force: float
    window: int = 3

    def reached(self, state: PressState, check: StopCheck) -> bool:
        recent = state.force_hist[-self.window :]
        return sum(recent) / len(recent) >= self.force


@dataclass(frozen=True)
class ThresholdRule:
    """The terminal check of Algorithm 1: stop once in contact and :func:`terminal_chamfer` >= ``threshold``."""

    threshold: float
    _rest: dict[str, object] = field(default_factory=dict, compare=False, repr=False)  # rest_terms, per rest layer

    def reached(self, state: PressState, check: StopCheck) -> bool:
        if not state.contact:
            return False
        if self._rest.get("x0") is not check.rest_cells:  # the same rest layer every step of a press
            self._rest.update(x0=check.rest_cells, terms=rest_terms(check.rest_cells, check.lattice))
        rest = self._rest["terms"]
        x, x0, lattice = check.contact_cells, check.rest_cells, check.lattice
        return chamfer_reaches(x, x0, lattice, self.threshold, rest=rest, memo=check.memo)  # type: ignore[arg-type]


@dataclass(frozen=True)
class DisplacementRule:
    """``PressConfig.terminal="displacement"`` (beyond the paper): stop once in contact and
    :func:`terminal_displacement` >= ``threshold``, the terminal check on the particle-matched deformation."""

    threshold: float

    def reached(self, state: PressState, check: StopCheck) -> bool:
        return state.contact and terminal_displacement(check.contact_cells, check.rest_cells) >= self.threshold


def threshold_cells(p: PressConfig) -> float:
    """The terminal threshold of ``p`` in squared cells of its own grid: ``threshold`` itself, or with
    ``threshold_grid`` = N (a threshold in squared cells of an N-cell grid, a physical unit) ``threshold * (n_grid /
    N)^2``: a length of one N-grid cell spans ``n_grid / N`` cells here."""
    if p.threshold is None:
        raise ValueError("threshold_cells needs a threshold")
    if p.threshold_grid is None:
        return float(p.threshold)
    return float(p.threshold) * (int(p.n_grid) / int(p.threshold_grid)) ** 2


def stop_rules(p: PressConfig, max_steps: int) -> list[StopRule]:
    """The ordered stop rules of ``p``: the travel limit, then the first configured of depth, force, threshold.

    ``p`` should have been through :func:`travel_for_depth`; ``max_steps`` is the press-phase step limit.
    """
    rules: list[StopRule] = [TravelLimit(int(max_steps), float(p.gap) + float(p.max_depth))]
    if p.depth is not None:
        rules.append(DepthRule(float(p.gap), float(p.depth)))
    elif p.force is not None:
        rules.append(ForceRule(float(p.force)))
    elif p.threshold is not None:
        rule = DisplacementRule if p.terminal == "displacement" else ThresholdRule
        rules.append(rule(threshold_cells(p)))
    return rules


def criterion_missed(rules: list[StopRule], state: PressState, check: StopCheck) -> bool:
    """After a stop: True when the press stopped on its travel limit while its own criterion (the depth, force or
    threshold rule of ``rules``) was configured and is not reached (e.g. ``depth`` deeper than the pad can travel,
    a ``force`` the material never builds up, a threshold the resolution cannot resolve)."""
    criteria = [r for r in rules if not isinstance(r, TravelLimit)]
    return bool(criteria) and not any(rule.reached(state, check) for rule in criteria)


def should_stop(rules: list[StopRule], state: PressState, check: StopCheck) -> bool:
    """Whether any rule, asked in order, says stop."""
    return any(rule.reached(state, check) for rule in rules)
