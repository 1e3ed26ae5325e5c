"""Scenes and helpers that benchmarks of more than one kind share (imported as ``benchmarks._common``).

Run a benchmark from the repository root as a module, e.g. ``python -m benchmarks.speed.bench_sim``, so that both
``tvrecon`` and ``benchmarks`` import without path edits.

- ``press_scene``: the solver scene of ``speed/bench_sim.py`` (a 48 x 48 x 12 pad above a sphere, n_grid 128);
- ``paper_scene`` / ``bench_scene`` (``SCENES``): press scenes of ``speed/bench_gpu.py``: the authors' pad with one
  object's paper sweep, and the solver scene as a press;
- ``tile``: touches repeated to fill a batch; ``same``: whether two placements are bit-identical.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import trimesh
from hydra.utils import instantiate

from tvrecon.data.presets import compose_preset
from tvrecon.data.touches.policies import sample_touches
from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig

ROOT = Path(__file__).resolve().parents[1]
"""The repository root (configs/, the git work tree)."""

N_GRID = 128
SPHERE_CENTER = (0.5, 0.5, 0.3)
SPHERE_RADIUS = 0.1


def press_scene(nx: int = 48, ny: int = 48, nz: int = 12, n_grid: int = N_GRID) -> tuple[torch.Tensor, ...]:
    """Pad particles (P, 3) float32 one cell above the sphere top, alpha (P,), hand velocity (3,), particle volume."""
    dx = 1.0 / n_grid
    h = 0.5 * dx
    ii = torch.arange(nx, dtype=torch.float64)
    jj = torch.arange(ny, dtype=torch.float64)
    kk = torch.arange(nz, dtype=torch.float64)
    g = torch.stack(torch.meshgrid(ii, jj, kk, indexing="ij"), -1).reshape(-1, 3)
    x = (g + 0.5) * h
    x[:, 0] += 0.5 - nx * h / 2
    x[:, 1] += 0.5 - ny * h / 2
    x[:, 2] += SPHERE_CENTER[2] + SPHERE_RADIUS + dx  # bottom layer one cell above the sphere
    alpha = torch.ones(x.shape[0])
    alpha[g[:, 2] == nz - 1] = 0.0  # back layer follows the hand
    hand = torch.tensor([0.0, 0.0, -0.125])  # ~4 cells in 200 CFL steps: 1 cell gap + 3 cells indentation
    return x.float(), alpha, hand, h**3


def paper_scene(device: str) -> tuple[SensorConfig, PressConfig, trimesh.Trimesh, torch.Tensor, torch.Tensor, dict]:
    """The authors' pad and grid with one object's paper sweep (``preset=paper``, first training object)."""
    cfg = compose_preset("paper", ["cache_dir=null"])
    ds = instantiate(cfg, _convert_="all").make_dataset("train")
    mesh = ds.mesh(0)
    sim = EIPSimulator(ds.sensor, ds.press, device=device)
    t = sample_touches(mesh, 10, seed=0, policy=ds.touch, sim=sim)
    if any(s != t.strengths[0] for s in t.strengths):
        raise RuntimeError("the paper sweep's touches of one object should share one stop rule")
    return ds.sensor, ds.press, mesh, t.positions, t.directions, dict(t.strengths[0])


def bench_scene(device: str) -> tuple[SensorConfig, PressConfig, trimesh.Trimesh, torch.Tensor, torch.Tensor, dict]:
    """``press_scene`` as a press: 48x48x12 pad, n_grid 128 on the unit domain, a sphere of radius 0.1."""
    sensor = SensorConfig(resolution=(48, 48), layers=12)
    press = PressConfig(n_grid=128, domain_size=1.0)
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    pos = torch.tensor([[0.0, 0.0, 0.1]])
    dirs = torch.tensor([[0.0, 0.0, -1.0]])
    return sensor, press, mesh, pos, dirs, {}


SCENES = {"paper": paper_scene, "bench": bench_scene}


def tile(x: torch.Tensor, b: int) -> torch.Tensor:
    """(T, 3) -> (b, 3): the touches repeated until the batch is full."""
    return x.repeat(math.ceil(b / x.shape[0]), 1)[:b]


def same(a, b) -> bool:
    """Both placements unreachable, or the same touch point and bit-identical collider tables."""
    if (a.collider is None) != (b.collider is None):
        return False
    if not torch.equal(a.origin, b.origin):
        return False
    ca, cb = a.collider, b.collider
    return ca is None or (
        torch.equal(ca.node_sdf, cb.node_sdf)
        and torch.equal(ca.node_normal, cb.node_normal)
        and ca.n_samples == cb.n_samples
    )
