"""The press loop hands the solver one per-particle hand velocity for as long as the touches' phases stay, and the
compiled step keeps its channel-first copy: no (B P, 3) expansion and no transpose copy per step (on the authors' pad,
batch 10, one CPU thread: ~3.5 ms of a ~95 ms compiled step, ``benchmarks/README.md``)."""

import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.sim.mpm.state import MPMConfig


def test_the_loop_passes_one_hand_velocity_while_the_phases_stay(monkeypatch):
    sim = EIPSimulator(SensorConfig(resolution=(6, 6), layers=4), PressConfig(n_grid=32, speed_fraction=0.3))
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    pos = torch.tensor([[0.0, 0.0, 0.2], [0.0, 0.0, 0.2]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    seen = []
    step = MLSMPM.step

    def spy(self, state, collider=None, hand_velocity=None, alpha=None):
        if hand_velocity is not None and hand_velocity.dim() == 2:
            seen.append((hand_velocity, alpha))  # held: no id is reused while the test runs
        return step(self, state, collider, hand_velocity, alpha)

    monkeypatch.setattr(MLSMPM, "step", spy)
    readings = sim.press_batch(mesh, pos, dirs)
    assert all(r.contact for r in readings) and len(seen) > 10
    # one tensor per set of phases (pressing, then released), not one per step
    assert len({id(h) for h, _ in seen}) <= 3 and len({id(a) for _, a in seen}) <= 3
    assert seen[0][0].shape == (2 * 6 * 6 * 4, 3)


def test_the_compiled_step_keeps_the_channel_first_copy_of_the_hand_velocity():
    solver = MLSMPM(MPMConfig(n_grid=16))
    hv = torch.randn(50, 3)
    first = solver._hand_cf(hv)
    assert first is solver._hand_cf(hv) and torch.equal(first, hv.T) and first.is_contiguous()
    hv.add_(1.0)  # changed in place: a fresh copy
    again = solver._hand_cf(hv)
    assert again is not first and torch.equal(again, hv.T)
    assert solver._hand_cf(hv.clone()) is not again  # another tensor with the same values: its own copy
    assert solver._hand_cf(torch.zeros(3)) is None and solver._hand_cf(None) is None
