"""Windows of unread steps (``PressLoop.read_every``): the press loop steps k times and reads the host once, then
replays each touch's stop checks on every step of the window. The readings are those of ``read_every=1``, bit for bit
on the CPU (each touch's reading is taken at its own stop step, kept by reference), also where a window has to run
again with a read each step: a block that outgrew its margin, a particle past the contact's skin, a fixed-step polar
that did not converge. In the GPU's layout a batch of 4 then pays at most one host sync a step."""

import warnings

import pytest
import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.mpm import materials
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.press import loop as loop_mod
from tvrecon.sim.press.loop import PressLoop
from tvrecon.utils.op_counter import per_step

GPU_LAYOUT = {"chunk_size": 0, "deferred_polar": True, "contact_skin": 0.5}


def _gpu_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in GPU_LAYOUT.items():
        monkeypatch.setattr(MLSMPM, name, value)


def _scene() -> tuple[EIPSimulator, trimesh.Trimesh, torch.Tensor, torch.Tensor]:
    """Four touches of a box that stop at different steps (a face, an edge, a tilted face, a side)."""
    sim = EIPSimulator(SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0))
    mesh = trimesh.creation.box(extents=(0.2, 0.15, 0.12))
    pos = torch.tensor([[0.0, 0.0, 0.06], [0.1, 0.075, 0.06], [0.03, 0.02, 0.06], [0.1, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [-1.0, -1.0, -1.0], [0.2, 0.1, -1.0], [-1.0, 0.0, 0.0]])
    return sim, mesh, pos, dirs


def _press(k: int) -> tuple[list, int]:
    """The scene's readings with ``read_every=k`` and how many windows ran again."""
    rewound: list[int] = []
    run, read_every = PressLoop.run, PressLoop.read_every

    def counted(self, places):  # noqa: ANN001, ANN202
        out = run(self, places)
        rewound.append(self.rewound)
        return out

    PressLoop.run, PressLoop.read_every = counted, k  # type: ignore[method-assign]
    try:
        sim, mesh, pos, dirs = _scene()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            readings = sim.press_batch(mesh, pos, dirs)
    finally:
        PressLoop.run, PressLoop.read_every = run, read_every  # type: ignore[method-assign]
    return readings, rewound[0]


@pytest.fixture(scope="module")
def every_gpu() -> list:
    """The scene pressed with a read every step, in the GPU's layout."""
    saved = {name: getattr(MLSMPM, name) for name in GPU_LAYOUT}
    for name, value in GPU_LAYOUT.items():
        setattr(MLSMPM, name, value)
    try:
        return _press(1)[0]
    finally:
        for name, value in saved.items():
            setattr(MLSMPM, name, value)


def _assert_same(a: list, b: list) -> None:
    """The same stops and, to float32 round-off, the same readings: a touch that stopped stays in the batch to its
    window's end, and a batch of another make-up rounds a few products differently (as a touch leaving the batch
    does with a read every step)."""
    assert len({r.steps for r in a}) > 1  # the touches stop at different steps, some inside a window
    for x, y in zip(a, b, strict=True):
        assert x.steps == y.steps and x.contact == y.contact and x.depth == y.depth
        assert x.chamfer == pytest.approx(y.chamfer, rel=1e-4)
        for name in ("image", "force", "force_field", "position"):
            assert torch.allclose(getattr(x, name), getattr(y, name), rtol=1e-3, atol=1e-5), name


def test_windows_give_the_readings_of_a_read_every_step(every_gpu, monkeypatch):
    _gpu_layout(monkeypatch)
    windows, rewound = _press(4)
    _assert_same(every_gpu, windows)
    assert rewound <= 3  # a window runs again only where the kept list or a block did not hold


def test_cpu_layout_windows_give_the_same_readings(monkeypatch):
    every, _ = _press(1)
    windows, rewound = _press(4)
    _assert_same(every, windows)
    assert rewound == 1  # the window in which the free flight ended: its speculative free step met the object
    monkeypatch.setattr(loop_mod, "FREE_FLIGHT", False)
    assert _press(4)[1] == 0  # no skin, no margin used up: nothing taken on trust failed


def test_a_window_whose_block_overflows_runs_again(every_gpu, monkeypatch):
    _gpu_layout(monkeypatch)
    monkeypatch.setattr(loop_mod, "WINDOW_MARGIN", -1)  # the padded block is too small from the second step on
    windows, rewound = _press(4)
    _assert_same(every_gpu, windows)
    assert rewound > 0


def test_a_window_past_the_skin_runs_again(every_gpu, monkeypatch):
    _gpu_layout(monkeypatch)
    monkeypatch.setattr(MLSMPM, "contact_skin", 0.02)  # particles move past it within a few steps
    windows, rewound = _press(4)
    _assert_same(every_gpu, windows)
    assert rewound > 0


def test_a_window_whose_fixed_polar_did_not_converge_runs_again(every_gpu, monkeypatch):
    _gpu_layout(monkeypatch)
    fixed = materials.polar_decomposition_fixed
    calls = [0]

    def flaky(F, *a, **kw):  # noqa: ANN001, ANN002, ANN003, ANN202
        R, ok = fixed(F, *a, **kw)
        calls[0] += 1
        return R, ok & (calls[0] % 7 != 0)  # every 7th step reports a particle that did not converge

    monkeypatch.setattr("tvrecon.sim.mpm.solver.polar_decomposition_fixed", flaky)
    windows, rewound = _press(4)
    _assert_same(every_gpu, windows)
    assert rewound > 0


def test_divergence_inside_a_window_raises_at_its_step(monkeypatch):
    _gpu_layout(monkeypatch)
    errors = []
    for k in (1, 4):
        monkeypatch.setattr(PressLoop, "read_every", k)
        sim = EIPSimulator(
            SensorConfig(resolution=(12, 12), layers=4, E=3e4),  # far too stiff for the step: it blows up
            PressConfig(n_grid=64, domain_size=1.0, dt=2e-3),
        )
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
        with pytest.raises(FloatingPointError) as e, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sim.press_batch(mesh, torch.tensor([[0.0, 0.0, 0.1]] * 2), torch.tensor([[0.0, 0.0, -1.0]] * 2))
        errors.append(str(e.value))
    assert errors[0] == errors[1], errors


def test_gpu_layout_with_windows_reads_the_host_at_most_once_a_step(monkeypatch):
    _gpu_layout(monkeypatch)
    monkeypatch.setattr(PressLoop, "read_every", 4)
    sim = EIPSimulator(SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1]]).repeat(4, 1)
    dirs = torch.tensor([[0.0, 0.0, -1.0]]).repeat(4, 1)
    sim.press_batch(mesh, pos, dirs, max_steps=2)

    def run(max_steps: int | None) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            limit = {} if max_steps is None else {"max_steps": max_steps}
            return max(int(r.steps) for r in sim.press_batch(mesh, pos, dirs, **limit))

    c = per_step(run)
    assert c["steps"] > 10
    assert c["syncs_per_step"] <= 1.0, c["syncs_by_op"]
