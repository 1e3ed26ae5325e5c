"""The press step's GPU shape, guarded on the CPU: aten ops and host syncs per step, counted with a
``TorchDispatchMode`` (:mod:`tvrecon.utils.op_counter`), stay flat in the batch size and under a budget.

Before the contact search and the stop checks were batched over touches, a batch of 4 paid 17.7 host syncs and
1,800 ops per step, growing with every touch (2 syncs and ~100 ops per touch per step: the per-scene mesh lookups and
the per-touch chamfer bound); on an H100 that made a press of 64 touches 33x slower than one (``bench_gpu.py``).
"""

import warnings

import pytest
import torch
import trimesh

from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig
from tvrecon.sim.mpm.solver import MLSMPM
from tvrecon.utils.op_counter import OpCounter, per_step

#: host syncs per step of the eager press on the CPU (measured 3.8 to 4.5 at batches 2 to 16: the polar
#: decomposition's convergence read (~1.4, one per Newton iteration, plus its CPU-only compaction), the contact
#: search's one compaction, and the loop's one read of forces, stop bounds, divergence, the solver's grid speed check
#: and the next step's block bounds; 5.9 to 6.9 before those two joined the loop's read)
SYNC_BUDGET = 5.5
#: the same on the GPU's layout, as on CUDA by default: the polar's convergence test rides on the loop's read
#: (``MLSMPM.deferred_polar``) and the contact keeps its candidate list over steps (``MLSMPM.contact_skin``): measured
#: 1.16 to 1.34 at batches 2 to 6, the loop's one read, a search every ~20 steps and each touch's stop checks (the
#: threshold rule's exact chamfer and the force field's finite check, ~2 per touch)
GPU_SYNC_BUDGET = 1.5
#: aten ops per step that launch a kernel (views excluded) on the GPU's layout: 416 at batch 4 before the launch diet
#: (the fixed-step polar 95 -> 46: lean Newton steps, two scaled and two plain, without the per-particle freeze;
#: contact passes 85 -> 47: the phi-only terms hoisted; mesh lookup 66 -> 40: broadcast corner products, packed
#: per-scene tables, a 3-add corner sum; B-spline weights 15 -> 8); measured 280 to 286 at batches 2 to 6
GPU_OP_BUDGET = 300


def _counts(batch: int, monkeypatch: pytest.MonkeyPatch, gpu: bool = False) -> dict:
    monkeypatch.setattr(MLSMPM, "chunk_size", 0)  # the GPU's layout: each stencil pass in one launch
    if gpu:  # and the rest of what CUDA does by default
        monkeypatch.setattr(MLSMPM, "deferred_polar", True)
        monkeypatch.setattr(MLSMPM, "contact_skin", 0.5)
        monkeypatch.setattr(MLSMPM, "node_major_p2g", True)
    sim = EIPSimulator(SensorConfig(resolution=(12, 12), layers=4), PressConfig(n_grid=64, domain_size=1.0))
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1]]).repeat(batch, 1)
    dirs = torch.tensor([[0.0, 0.0, -1.0]]).repeat(batch, 1)
    sim.press_batch(mesh, pos, dirs, max_steps=2)  # placement and tables cached, as in a real run

    def run(max_steps: int | None) -> int:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            limit = {} if max_steps is None else {"max_steps": max_steps}
            return max(int(r.steps) for r in sim.press_batch(mesh, pos, dirs, **limit))

    return per_step(run)


def test_syncs_and_ops_per_step_do_not_grow_with_the_batch(monkeypatch):
    small, large = _counts(2, monkeypatch), _counts(6, monkeypatch)
    assert small["steps"] > 10 and large["steps"] == small["steps"]
    for c in (small, large):
        assert c["syncs_per_step"] <= SYNC_BUDGET, c["syncs_by_op"]
    assert large["syncs_per_step"] <= small["syncs_per_step"] + 0.5, (small["syncs_by_op"], large["syncs_by_op"])
    # ops: the same launches whatever the batch (a loop over touches would add ~100 per touch per step)
    assert large["launch_ops_per_step"] <= small["launch_ops_per_step"] + 20, (small["top_ops"], large["top_ops"])


def test_gpu_layout_reads_the_host_about_once_a_step(monkeypatch):
    small, large = _counts(2, monkeypatch, True), _counts(6, monkeypatch, True)
    for c in (small, large):
        assert c["syncs_per_step"] <= GPU_SYNC_BUDGET, c["syncs_by_op"]
        assert c["syncs_by_op"].get("nonzero", 0) <= 0.2, c["syncs_by_op"]  # the contact searches now and then
        assert c["launch_ops_per_step"] <= GPU_OP_BUDGET, c["top_ops"]
    assert large["syncs_per_step"] <= small["syncs_per_step"] + 0.5, (small["syncs_by_op"], large["syncs_by_op"])


def test_op_counter_counts_syncs_and_restores_tolist():
    t = torch.arange(6.0)
    tolist = torch.Tensor.tolist
    with OpCounter() as c:
        (t * 2).sum().item()
        torch.nonzero(t > 2)
        t[t > 3]
        t.tolist()
    assert torch.Tensor.tolist is tolist
    assert c.ops["mul"] == 1 and c.ops["sum"] == 1
    assert c.syncs["_local_scalar_dense"] == 1 and c.syncs["nonzero"] == 1 and c.syncs["tolist"] == 1
    assert c.syncs["index(bool mask)"] == 1
