"""``PressConfig.collider_refine``: the object's distance table sampled finer than the grid holds parts thinner than a
grid cell (a spoon's bowl, a screwdriver's shaft on the CPU presets' 64 grid), and leaves thick bodies as they were.

Physics against physics: a plate under half a cell thick is not felt on the grid's own nodes (the control) and is
felt on a table twice as fine; a sphere ten cells across reads the same image to round-off of the lookup, and the
table's refinement converges (2 is nearer 3 than 1 is)."""

import pytest
import torch
import trimesh

from tvrecon.data.cache.store import cache_key
from tvrecon.sim.bodies.colliders import MeshCollider
from tvrecon.sim.bodies.grid_contact import collider_at_block
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor.elastic_pad import SensorConfig

PAD = SensorConfig(resolution=(8, 8), layers=3)


@pytest.mark.parametrize("bad", [0, 5, -1])
def test_refine_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="collider_refine"):
        PressConfig(collider_refine=bad)


def test_refine_must_be_whole():
    with pytest.raises((TypeError, ValueError), match="collider_refine"):
        PressConfig(collider_refine=1.5)
    with pytest.raises(TypeError, match="collider_refine"):
        PressConfig(collider_refine="2")


def test_default_refine_stays_out_of_the_cache_key():
    """The default (1) is the earlier press: its data keeps its keys; any other value is another dataset."""
    base = cache_key({"press": PressConfig(n_grid=64)})
    assert cache_key({"press": PressConfig(n_grid=64, collider_refine=1)}) == base
    assert cache_key({"press": PressConfig(n_grid=64, collider_refine=2)}) != base


def _plate(thickness_cells: float, n_grid: int) -> trimesh.Trimesh:
    """A 0.5 x 0.5 plate ``thickness_cells`` grid cells thick (world units = domain units here), tilted 0.3 rad."""
    mesh = trimesh.creation.box(extents=[0.5, 0.5, thickness_cells / n_grid])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.3, [1.0, 0.0, 0.0]))
    return mesh


def test_a_plate_thinner_than_a_cell_is_felt_only_on_a_finer_table():
    """0.3 cells thick: both table nodes astride it lie outside, so on the grid's own nodes the interpolated distance
    never goes negative and the pad passes through (no force, a blank image); a table twice as fine holds it."""
    n = 32
    reads = {}
    for r in (1, 2):
        sim = EIPSimulator(PAD, PressConfig(n_grid=n, collider_refine=r, depth=1.0))
        reads[r] = sim.press(_plate(0.3, n), [0.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    assert float(reads[1].force.norm()) < 1e-6 and float(reads[1].image.abs().max()) < 1e-3
    assert float(reads[2].force.norm()) > 1e-3 and float(reads[2].image.abs().max()) > 0.03
    assert reads[1].steps == reads[2].steps  # the same press: only the object's table differs


def test_a_thick_body_reads_the_same_and_the_refinement_converges():
    """A sphere 19 cells across: the image moves by ~1% of its depth from 1 to 2, and 2 lies nearer 3 than 1 does."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    img = {}
    for r in (1, 2, 3):
        sim = EIPSimulator(PAD, PressConfig(n_grid=32, collider_refine=r, depth=1.0))
        img[r] = sim.press(mesh, [0.0, 0.0, 0.3], [0.0, 0.0, -1.0]).image
    depth = float(img[3].abs().max())
    assert depth > 0.5
    assert float((img[2] - img[1]).abs().max()) < 0.03 * depth
    assert float((img[2] - img[3]).abs().max()) < 0.5 * float((img[1] - img[3]).abs().max())


def test_grid_contact_interpolates_a_finer_table_at_its_nodes():
    """A table finer than the grid is not the grid's nodes: ``collider_at_block`` interpolates it at the node
    positions (a table of the grid's own spacing is gathered, as before)."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    mesh.apply_translation([0.5, 0.5, 0.5])
    n, lo, D = 32, (12, 13, 14), (5, 4, 6)
    fine = MeshCollider(mesh, n_grid=2 * n)
    sdf, nrm = collider_at_block(fine, lo, D, 1.0 / n, torch.float32, "cpu")
    idx = torch.stack(torch.meshgrid(*(torch.arange(a, a + d) for a, d in zip(lo, D)), indexing="ij"), -1)
    pos = idx.reshape(-1, 3).float() / n
    assert torch.equal(sdf, fine.sdf(pos)) and torch.equal(nrm, fine.normal(pos))
    own = MeshCollider(mesh, n_grid=n)
    sdf1, _ = collider_at_block(own, lo, D, 1.0 / n, torch.float32, "cpu")
    assert torch.equal(sdf1, own.at_block(lo, D, "cpu")[0])
    # the same body, sampled finer (within 2 grid cells of its surface: each table caps the distance at 4 of its cells)
    near = sdf1.abs() < 1.5 / n
    assert int(near.sum()) >= 10 and float((sdf - sdf1)[near].abs().max()) < 0.25 / n
