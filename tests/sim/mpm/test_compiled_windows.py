"""The compiled step on the GPU's layout takes the eager step's deferred reads: its block dims come with
the last step's host read (planned from the new positions), the fixed-step polar's convergence with its own, and
inside a window of unread steps (``PressLoop.read_every``) the dims are trusted with a margin and the indices clamped.
It then reads the host at most once a step, where it read twice (``grid.block_dims`` and the polar flag), and gives
the eager press's readings, also where a window has to run again."""

import warnings

import pytest
import torch
import trimesh
from test_mpm_compile import needs_compiler

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.mpm.compiled import step as step_mod
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.press import loop as loop_mod
from tvrecon.sim.press.loop import PressLoop
from tvrecon.utils.op_counter import ProfiledCounter, per_step

GPU_LAYOUT = {"chunk_size": 0, "deferred_polar": True, "contact_skin": 0.5, "node_major_p2g": True}

pytestmark = needs_compiler


@pytest.fixture()
def gpu_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in GPU_LAYOUT.items():
        monkeypatch.setattr(MLSMPM, name, value)
    monkeypatch.setattr(PressLoop, "read_every", 4)


def _scene() -> tuple[SensorConfig, PressConfig, trimesh.Trimesh, torch.Tensor, torch.Tensor]:
    """Four touches of a box that stop at different steps (a face, an edge, a tilted face, a side)."""
    mesh = trimesh.creation.box(extents=(0.2, 0.15, 0.12))
    pos = torch.tensor([[0.0, 0.0, 0.06], [0.1, 0.075, 0.06], [0.03, 0.02, 0.06], [0.1, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [-1.0, -1.0, -1.0], [0.2, 0.1, -1.0], [-1.0, 0.0, 0.0]])
    return SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0), mesh, pos, dirs


def _press(compile: bool) -> tuple[list, int]:
    sensor, press, mesh, pos, dirs = _scene()
    rewound: list[int] = []
    run = PressLoop.run

    def counted(self, places):  # noqa: ANN001, ANN202
        out = run(self, places)
        rewound.append(self.rewound)
        return out

    PressLoop.run = counted  # type: ignore[method-assign]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return EIPSimulator(sensor, press, compile=compile).press_batch(mesh, pos, dirs), rewound[0]
    finally:
        PressLoop.run = run  # type: ignore[method-assign]


def _assert_close(eager: list, compiled: list) -> None:
    assert len({r.steps for r in eager}) > 1  # the touches stop at different steps, some inside a window
    for r, n in zip(eager, compiled, strict=True):
        assert r.contact and n.contact and r.steps == n.steps
        assert (n.image - r.image).abs().max() <= 1e-4  # compile=True's stated tolerance, in grid cells
        torch.testing.assert_close(n.force, r.force, rtol=1e-4, atol=1e-6)


@pytest.mark.slow
def test_compiled_windows_read_what_the_eager_windows_read(gpu_layout, monkeypatch):
    dims_read: list[bool] = []
    fused = step_mod.fused_step

    def spy(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        dims_read.append(kwargs.get("dims") is None)
        return fused(*args, **kwargs)

    monkeypatch.setattr("tvrecon.sim.mpm.solver.fused_step", spy)
    eager, _ = _press(False)
    compiled, rewound = _press(True)
    _assert_close(eager, compiled)
    assert rewound <= 3
    # the dims came with the loop's read but at the press's first step and the first step after touches left the
    # batch (a new state, as in the eager step)
    assert len(dims_read) > 20 and sum(dims_read) <= len({r.steps for r in compiled}), sum(dims_read)


@pytest.mark.slow
def test_a_compiled_window_whose_block_overflows_runs_again_and_reads_the_same(gpu_layout, monkeypatch):
    eager, _ = _press(False)
    monkeypatch.setattr(loop_mod, "WINDOW_MARGIN", -1)  # the padded block is too small: clamped, then run again
    compiled, rewound = _press(True)
    _assert_close(eager, compiled)
    assert rewound >= 3


@pytest.mark.slow
def test_a_compiled_polar_that_did_not_converge_runs_the_step_again_iterating(gpu_layout, monkeypatch):
    eager, _ = _press(False)
    calls = {"n": 0}
    polar = step_mod.polar_decomposition

    def counted(F):  # noqa: ANN001, ANN202
        calls["n"] += 1
        return polar(F)

    monkeypatch.setattr(step_mod, "polar_decomposition", counted)
    monkeypatch.setattr(step_mod, "polar_grid_available", lambda *t: False)  # the kernel below, also on one thread
    kernels_call = step_mod.CompiledKernels.__call__

    def flaky(self, name, *args):  # noqa: ANN001, ANN002, ANN202
        out = kernels_call(self, name, *args)
        if name == "polar":
            flaky.n += 1
            if flaky.n in (3, 7, 30, 34):  # "did not converge": a window's third step, then a step of its rerun
                out = (out[0], torch.zeros((), dtype=torch.bool))
        return out

    flaky.n = 0
    monkeypatch.setattr(step_mod.CompiledKernels, "__call__", flaky)
    compiled, _ = _press(True)
    _assert_close(eager, compiled)
    assert calls["n"] >= 2  # the reruns took the iterating polar


@pytest.mark.slow
def test_the_compiled_gpu_layout_reads_the_host_at_most_once_a_step(gpu_layout):
    sensor, press, _, _, _ = _scene()
    sim = EIPSimulator(sensor, press, compile=True)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1]]).repeat(4, 1)
    dirs = torch.tensor([[0.0, 0.0, -1.0]]).repeat(4, 1)

    def run(max_steps: int | None) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            limit = {} if max_steps is None else {"max_steps": max_steps}
            return max(int(r.steps) for r in sim.press_batch(mesh, pos, dirs, **limit))

    run(2)  # compile
    c = per_step(run, ProfiledCounter)
    assert c["steps"] > 10
    assert c["syncs_per_step"] <= 1.0, c["syncs_by_op"]  # 2.3 before: the step's own dims and polar reads
