"""The paper's touches (tvrecon.data.touches.sweep): centre aim, side-to-top sweep, depth, the presets' ratios, and a
touch that misses a thin part, a diverging touch."""

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from omegaconf import OmegaConf

from tvrecon.data.task_datasets import TactileClassificationDataset
from tvrecon.data.touches.policies import make_touch_policy, sample_touches
from tvrecon.data.touches.report import contact_report
from tvrecon.data.touches.sweep import AUTHORS_RATIOS, PaperSweepTouchPolicy, eip_geometry_ratios, sweep_directions
from tvrecon.sim import EIPSimulator, PressConfig, SensorConfig

pytestmark = pytest.mark.usefixtures("one_thread")

CONFIGS = Path(__file__).resolve().parents[3] / "configs" / "data"


def _block(group: str, name: str) -> dict:
    cfg = OmegaConf.load(CONFIGS / group / f"{name}.yaml")
    out = {}
    for d in cfg.pop("defaults", []):
        if d != "_self_":
            out.update(OmegaConf.to_container(OmegaConf.load(CONFIGS / group / f"{d}.yaml")))
    out.update(OmegaConf.to_container(cfg))
    return out


def _tiny_sim() -> EIPSimulator:
    return EIPSimulator(SensorConfig(**_block("sensor", "eip_tiny")), PressConfig(**_block("press", "eip_tiny")))


def test_sweep_directions_go_from_the_side_to_the_top() -> None:
    d = sweep_directions(0.3, np.array([0.0, 45.0, 90.0]))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert abs(d[0, 2]) < 1e-12 and np.allclose(d[0, :2], [-np.cos(0.3), -np.sin(0.3)])  # horizontal, into the object
    assert np.allclose(d[2], [0.0, 0.0, -1.0])  # from the top: straight down
    assert np.isclose(np.degrees(np.arcsin(-d[1, 2])), 45.0)


def test_policy_aims_through_the_centre_sweeps_evenly_and_sizes_the_depth() -> None:
    sim = _tiny_sim()
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    box.apply_translation([0.2, -0.1, 0.05])
    t = sample_touches(box, 10, seed=3, policy=make_touch_policy(_block("touch", "paper_sweep")), sim=sim)
    off = t.positions.double() - torch.tensor(box.bounds.mean(0))  # (10, 3) from the centre to each start
    d = t.directions.double()
    assert torch.linalg.cross(off, d).norm(dim=1).max() < 1e-6  # on the centre line through the box's centre
    ahead = (torch.tensor(box.vertices) - t.positions.double()[:, None]) @ -d[:, :, None]  # (10, 8, 1) along -d
    assert ahead.max() < 1e-5 and ahead.amax(dim=1).min() > -1e-5  # the start bounds the box on the pad's side
    elev = np.degrees(np.arcsin(-t.directions[:, 2].double().numpy()))
    assert np.allclose(elev, np.linspace(0.0, 90.0, 10), atol=1e-4)
    horizontal = t.directions[:-1, :2].double().numpy()
    azimuths = np.arctan2(horizontal[:, 1], horizontal[:, 0])
    assert np.allclose(azimuths, azimuths[0], atol=1e-5)  # one vertical plane per object
    extent_cells = 1.0 / sim.cfg.domain_size * sim.cfg.n_grid
    assert all(s == {"depth": round(0.12 * extent_cells, 4)} for s in t.strengths)
    other = sample_touches(box, 10, seed=4, policy=PaperSweepTouchPolicy(), sim=sim)
    assert not torch.allclose(other.directions[0], t.directions[0])  # the azimuth is drawn per object


def test_policy_needs_the_simulator_and_checks_its_fields() -> None:
    box = trimesh.creation.box()
    with pytest.raises(ValueError, match="pass sim="):
        sample_touches(box, 3, seed=0, policy=PaperSweepTouchPolicy())
    with pytest.raises(ValueError, match="depth_fractions"):
        PaperSweepTouchPolicy(depth_fractions=[0.7])
    with pytest.raises(ValueError, match="elevation_deg"):
        PaperSweepTouchPolicy(elevation_deg=[0.0, 120.0])
    with pytest.raises(ValueError, match="aim"):
        PaperSweepTouchPolicy(aim="corner")
    with pytest.raises(ValueError, match="start"):
        PaperSweepTouchPolicy(start="inside")


def test_a_cube_pressed_at_45_degrees_is_placed_from_outside_on_the_authors_grid() -> None:
    """On the authors' 128 grid a cube reaches 0.71 of its side (14.5 cells) from its centre along a 45-degree press,
    past the 12 cells in front of the aim where the pad's rays start: aimed from the centre the pad is placed inside
    it and the touch is rejected (the dataset then re-drew it off the sweep); started where the centre line leaves
    the cube, the same touch is placed with its touch point on the cube's corner plane."""
    sim = EIPSimulator(SensorConfig(**_block("sensor", "eip")), PressConfig(**_block("press", "eip")))
    cube = trimesh.creation.box()
    cell = sim.cfg.domain_size / sim.cfg.n_grid
    for start in ("centre", "outside"):
        t = sample_touches(cube, 1, seed=0, policy=PaperSweepTouchPolicy(elevation_deg=[45, 45], start=start), sim=sim)
        if start == "centre":
            with pytest.raises(ValueError, match="start inside the object"):
                sim.place_batch(cube, t.positions, t.directions)
            continue
        (placed,) = sim.place_batch(cube, t.positions, t.directions)
        assert placed.reachable
        reach = float((torch.tensor(cube.vertices, dtype=torch.float32) @ -t.directions[0]).max())
        assert reach > 0.7 and float(placed.origin @ -t.directions[0]) == pytest.approx(reach, abs=1.5 * cell)
        assert float(torch.linalg.cross(placed.origin, t.directions[0]).norm()) < 1e-4  # still through the centre


@pytest.mark.parametrize(
    ("sensor", "press", "tol"), [("eip", "eip", 0.03), ("eip_cpu", "eip_cpu", 0.06), ("eip_tiny", "eip_tiny", 0.1)]
)
def test_presets_keep_the_authors_ratios(sensor: str, press: str, tol: float) -> None:
    r = eip_geometry_ratios(SensorConfig(**_block("sensor", sensor)), PressConfig(**_block("press", press)))
    assert r["object_fraction"] == pytest.approx(AUTHORS_RATIOS["object_fraction"])
    assert r["pad_ratio"] == pytest.approx(AUTHORS_RATIOS["pad_ratio"], rel=tol)
    assert r["thickness_ratio"] == pytest.approx(AUTHORS_RATIOS["thickness_ratio"], rel=0.25)
    if sensor == "eip":  # the authors' own pad: 61 x 10 x 61 particles on 128^3
        assert r["pad_particles"] == 61 * 61 * 10 and r["object_cells"] == pytest.approx(20.48)


def test_a_top_press_shows_the_whole_face_and_a_sphere_reads_round() -> None:
    """The pad larger than the object reads the object's outline: a cube's top face is a square of pushed-in taxels
    the size of the face, a sphere's a small round cap (control: same pad, same depth)."""
    sim = _tiny_sim()
    policy = PaperSweepTouchPolicy(elevation_deg=[90.0, 90.0])
    spacing_world = sim.sensor.spacing * sim.cfg.domain_size / sim.cfg.n_grid
    areas = {}
    for name, mesh in {"cube": trimesh.creation.box(), "sphere": trimesh.creation.icosphere(3, radius=0.5)}.items():
        t = sample_touches(mesh, 1, seed=0, policy=policy, sim=sim)
        r = sim.press_batch(mesh, t.positions, t.directions, **t.strengths[0])[0]
        assert bool(r.contact)
        pushed = r.image[2] > 0.5 * float(r.image[2].max())
        areas[name] = int(pushed.sum())
    face_taxels = (1.0 / spacing_world) ** 2
    assert 0.6 * face_taxels < areas["cube"] < 1.2 * face_taxels
    assert areas["sphere"] < 0.5 * areas["cube"]


def test_a_touch_that_misses_a_thin_part_reads_blank_and_is_reported_per_class(tmp_path: Path) -> None:
    """The fork's tines and handle are under a cell thick on eip_tiny's grid: some sweep touches never feel it. They
    stay blank readings with ``contact`` False (control: the cube in the same dataset feels every touch), and
    ``contact_report`` counts them per class from the cache."""
    ds = TactileClassificationDataset(
        num_objects=6,
        classes=["cube", "fork"],
        touches_per_object=10,
        touch=_block("touch", "paper_sweep"),
        cache_dir=tmp_path,
        sensor=_block("sensor", "eip_tiny"),
        press=_block("press", "eip_tiny"),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        cube, fork = ds.raw(0)[0], ds.raw(1)[0]
    assert cube["contact"].all() and (~fork["contact"]).sum() >= 2
    assert np.abs(fork["tactile"][~fork["contact"]]).max() < 0.01  # blank, not noise
    assert fork["tactile"][fork["contact"], 2].max() > 0.02  # what it felt is faint: under a cell thick
    report = contact_report(ds)
    assert report.items_missing == 4 and report.missed == {"cube": 0, "fork": int((~fork["contact"]).sum())}
    assert report.total == {"cube": 10, "fork": 10} and "fork" in report.line() and "cube" not in report.line()


def test_a_diverging_touch_is_pressed_again_with_a_smaller_step() -> None:
    """A touch of the shared_base pear (instance 3, its seventh touch: the stem, about a cell thick, from 60 degrees)
    diverges at the CPU presets' CFL step on the grid's own table nodes; the dataset presses it alone with half the
    step and reads it. With the presets' table at 1/128 (``collider_refine: 2``) the stem is held and the same touch
    does not diverge."""
    from tvrecon.data.shapes import ObjectLibrary

    ds = TactileClassificationDataset(
        num_objects=129,
        touches_per_object=10,
        touch=_block("touch", "paper_sweep"),
        library=ObjectLibrary(protocol="shared_base"),
        cache_dir=None,
        sensor=_block("sensor", "eip_cpu"),
        press={**_block("press", "eip_cpu"), "collider_refine": 1},
    )
    assert ds.object_of(128) == ("pear", 3)
    mesh = ds.mesh(128)
    t = sample_touches(mesh, 10, seed=ds.seeds(128)[0], policy=ds.touch, sim=ds.simulator)
    one = t._replace(
        positions=t.positions[6:7], directions=t.directions[6:7], normals=t.normals[6:7], strengths=t.strengths[6:7]
    )
    with pytest.raises(FloatingPointError, match="diverged"):
        ds.simulator.press_batch(mesh, one.positions, one.directions, **one.strengths[0])
    (reading,) = ds._simulate_stable(mesh, one)
    assert torch.isfinite(reading.image).all() and reading.steps > 0
    fine = ds.simulator.press_batch(mesh, one.positions, one.directions, collider_refine=2, **one.strengths[0])
    assert torch.isfinite(fine[0].image).all() and fine[0].contact


def test_a_touch_that_diverges_at_every_step_is_pressed_with_the_grid_contact(monkeypatch, caplog) -> None:
    """A touch whose particle-contact press diverges at every step size (as the shared_base mug's handle from the side
    on ``cls_paper``) is pressed with the grid contact, with a warning naming the item and the touch; the others keep
    the particle contact. When the grid contact diverges too, the error stands."""
    import logging

    from tvrecon.data import dataset_base as generated_dataset

    ds = TactileClassificationDataset(
        num_objects=1,
        touches_per_object=3,
        touch=_block("touch", "paper_sweep"),
        cache_dir=None,
        sensor=_block("sensor", "eip_tiny"),
        press=_block("press", "eip_tiny"),
    )
    assert ds.simulator.cfg.contact == "particle"
    real = generated_dataset.simulate_touches
    calls = []

    def flaky(sim, mesh, touches, batch_size=1, grid_too=False):  # noqa: ANN001, ANN202
        change = touches.strengths[0]
        calls.append((len(touches.strengths), change.get("dt"), change.get("contact")))
        bad = len(touches.strengths) > 1 or (float(touches.directions[0, 2]) > -0.5 and change.get("contact") is None)
        if bad or (grid_too and change.get("contact") == "grid"):
            raise FloatingPointError("MPM state exploded")
        return real(sim, mesh, touches, batch_size=batch_size)

    monkeypatch.setattr(generated_dataset, "simulate_touches", flaky)
    with caplog.at_level(logging.WARNING, logger=generated_dataset.__name__):
        item = ds.raw(0)[0]
    side = [t for t in range(3) if float(item["directions"][t, 2]) > -0.5]  # the sweep's side touch (0 degrees)
    assert side == [0] and item["contact"].all() and np.abs(item["tactile"]).max() > 0.05
    assert [c for c in calls if c[2] == "grid"] == [(1, None, "grid")]  # after the batch, the press alone, 3 halvings
    assert sum(1 for c in calls if c[0] == 1 and c[2] is None) == 4 + 2  # touch 0: 4 step sizes; 1, 2: once each
    (msg,) = [r.getMessage() for r in caplog.records if "grid contact" in r.getMessage()]
    assert "train item 0 (" in msg and "touch 0" in msg and "dt / 8" in msg
    monkeypatch.setattr(generated_dataset, "simulate_touches", lambda *a, **k: flaky(*a, **{**k, "grid_too": True}))
    mesh = ds.mesh(0)
    with pytest.raises(FloatingPointError, match="exploded"):
        ds._simulate_stable(mesh, sample_touches(mesh, 3, seed=0, policy=ds.touch, sim=ds.simulator))


def test_shuffled_order_is_the_same_sweep_and_sweep_order_keeps_the_key() -> None:
    sim = _tiny_sim()
    box = trimesh.creation.box()
    swept = sample_touches(box, 10, seed=5, policy=PaperSweepTouchPolicy(), sim=sim)
    shuffled = sample_touches(box, 10, seed=5, policy=PaperSweepTouchPolicy(order="shuffled"), sim=sim)
    order = np.argsort(-shuffled.directions[:, 2].numpy())  # the sweep's elevation rises with -d_z
    assert torch.allclose(shuffled.directions[order], swept.directions, atol=1e-6)
    assert not torch.allclose(shuffled.directions, swept.directions)
    assert "order" not in PaperSweepTouchPolicy().cache_spec()  # the default stays out of the cache key
    assert PaperSweepTouchPolicy().cache_spec()["start"] == "outside"  # caches of centre starts are not misread
    assert PaperSweepTouchPolicy(order="shuffled").cache_spec()["order"] == "shuffled"


def test_a_touch_the_simulator_rejects_is_redrawn_with_a_warning_naming_the_item(caplog, tmp_path: Path) -> None:
    """With the old centre start on the authors' grid, the cube's 45-degree touches are rejected (the pad would start
    inside it); the dataset re-draws them one by one, off the sweep, and says so once, naming the item (control: the
    touches that were placed are kept as drawn)."""
    ds = TactileClassificationDataset(
        num_objects=1,
        classes=["cube"],
        touches_per_object=10,
        touch={**_block("touch", "paper_sweep"), "start": "centre"},
        cache_dir=tmp_path,
        sensor=_block("sensor", "eip"),
        press=_block("press", "eip"),
    )
    mesh = ds.mesh(0)
    touches = sample_touches(mesh, 10, seed=7, policy=ds.touch, sim=ds.simulator)
    with caplog.at_level("WARNING", logger="tvrecon.data.dataset_base"):
        fixed = ds._placeable_touches(mesh, touches, seed=7, index=0)
    kept = (fixed.directions == touches.directions).all(dim=1)
    assert 0 < int((~kept).sum()) < 10
    (msg,) = [r.getMessage() for r in caplog.records if "re-drawn" in r.getMessage()]
    assert "item 0 (cube 0)" in msg and f"{int((~kept).sum())} of 10 touches" in msg and "start inside" in msg
