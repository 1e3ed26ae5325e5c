"""The MuJoCo TactileSensor: contacts read from MjData, the touched geom's own surface pressed, rest without contact."""

import os

import numpy as np
import pytest
import trimesh

os.environ.setdefault("MUJOCO_GL", "egl")  # mujoco reads it once, at import: keep later rendering tests headless
mujoco = pytest.importorskip("mujoco")

from tvrecon.robot.mujoco.sensor import TactileSensor, geom_mesh  # noqa: E402
from tvrecon.robot.pad_config import PadConfig  # noqa: E402
from tvrecon.robot.pad_sensor import sense_pads  # noqa: E402

# a free box (top face at z = 0.01) between two mocap pads; no gravity, so the poses stay as set
XML = """
<mujoco>
  <option gravity="0 0 0"/>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.02 0 0  0 0.02 0  0 0 0.02"/>
  </asset>
  <worldbody>
    <body name="obj"><freejoint/><geom name="box" type="box" size="0.03 0.03 0.01" mass="0.1"/></body>
    <body name="top" mocap="true" pos="0 0 0.05"><geom name="top" type="box" size="0.006 0.006 0.005"/></body>
    <body name="bottom" mocap="true" pos="0 0 -0.05"><geom name="bottom" type="box" size="0.006 0.006 0.005"/></body>
    <body name="shapes" pos="1 0 0">
      <geom name="sphere" type="sphere" size="0.02" contype="0" conaffinity="0"/>
      <geom name="capsule" type="capsule" size="0.01 0.03" contype="0" conaffinity="0"/>
      <geom name="cylinder" type="cylinder" size="0.015 0.025" contype="0" conaffinity="0"/>
      <geom name="tet" type="mesh" mesh="tet" contype="0" conaffinity="0"/>
      <geom name="floor" type="plane" size="0 0 1" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
</mujoco>
"""
PAD = PadConfig(resolution=(8, 8), layers=3, pad_size=0.01, n_grid=32, stiffness=1e9, min_force=0.0)


@pytest.fixture()
def scene():
    """Pads that press by MuJoCo's penetration (``use_penetration``; the stiff PAD's give is ~0): a known depth."""
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    kw = {"pad": PAD, "up_axis": (1, 0, 0), "use_penetration": True}
    top = TactileSensor(model, data, geom="top", normal_axis=(0, 0, -1), **kw)
    bottom = TactileSensor(model, data, geom="bottom", normal_axis=(0, 0, 1), simulator=top.sim, **kw)
    return model, data, top, bottom


def press_by(model, data, top: float, bottom: float | None = None) -> None:
    """Put the pads ``top`` / ``bottom`` metres into the box's top / bottom face (None: far away)."""
    data.mocap_pos[0] = [0.0, 0.0, 0.015 - top]
    data.mocap_pos[1] = [0.0, 0.0, -0.05 if bottom is None else -0.015 + bottom]
    mujoco.mj_forward(model, data)


def test_a_known_press_gives_contact_and_the_normal_displacement(scene) -> None:
    model, data, top, _ = scene
    press_by(model, data, 0.001)
    r = top.sense()
    cells = 0.001 / PAD.dx  # 0.35 cells
    assert r.contact and r.simulated and r.body == 0  # the box geom
    assert r.penetration == pytest.approx(0.001, abs=1e-6) and r.depth == pytest.approx(0.001, abs=1e-9)
    assert np.allclose(r.direction, (0, 0, -1))
    assert r.force > 0 and r.force_vec[2] > 0  # the box pushes the top pad up
    assert r.image.shape == (3, 8, 8) and r.image.dtype == np.float32
    assert (r.image[2] > 0).all()  # the flat face pushes the whole pad in
    assert 0.7 * cells < r.image[2].mean() < 1.1 * cells
    assert np.abs(r.image[:2]).max() < 0.2 * r.image[2].mean()  # a straight press: little shear
    assert r.patch.shape == (64, 3)  # every taxel in contact, on the box's top face, under the pad
    assert np.abs(r.patch[:, 2] - 0.01).max() < 0.5e-3 and np.abs(r.patch[:, :2]).max() < 0.006
    assert r.force_field.shape == (3, 8, 8) and r.force_field[2].sum() > 0
    assert r.rgb().shape == (3, 8, 8) and r.markers()[0].shape[1] == 2
    again = top.sense()
    assert not again.simulated and np.array_equal(again.image, r.image)  # cached: nothing changed
    assert top.num_presses == 1


def test_by_default_the_depth_is_the_pads_give_under_mujocos_force(scene) -> None:
    model, data, top, _ = scene
    press_by(model, data, 0.001, 0.001)  # the box squeezed 1 mm between the pads
    force = sum(p.force for p in top.contact_points())
    assert force > 0
    pad = PadConfig(resolution=(8, 8), layers=3, pad_size=0.01, n_grid=32, stiffness=force / 4e-4)  # give: 0.4 mm
    s = TactileSensor(model, data, geom="top", pad=pad, normal_axis=(0, 0, -1), up_axis=(1, 0, 0))
    r = s.sense()
    assert r.contact and r.force == pytest.approx(force)
    assert r.penetration == pytest.approx(0.001, abs=1e-6) and r.depth == pytest.approx(4e-4, abs=1e-9)
    cells = r.depth / pad.dx
    assert 0.7 * cells < r.image[2].mean() < 1.1 * cells


def test_no_contact_is_the_rest_reading_without_simulation(scene) -> None:
    model, data, top, bottom = scene
    press_by(model, data, 0.001)
    top.sense()
    press_by(model, data, -0.01)  # 1 cm above the box
    r = top.sense()
    assert not r.contact and not r.simulated and r.force == 0.0 and r.body == -1
    assert not r.image.any() and not r.force_field.any() and r.patch.shape == (0, 3)
    assert np.isnan(r.position).all() and top.num_presses == 1
    rb = bottom.sense()
    assert not rb.contact and bottom.num_presses == 0


def test_two_pads_in_one_batch_equal_two_single_presses(scene) -> None:
    model, data, top, bottom = scene
    press_by(model, data, 0.001, 0.001)
    both = sense_pads([top, bottom])
    assert all(r.contact and r.simulated for r in both)
    top.reset()
    bottom.reset()
    single = [top.sense(), bottom.sense()]
    for b, s in zip(both, single):
        np.testing.assert_allclose(b.image, s.image, atol=1e-5)
        np.testing.assert_allclose(b.patch, s.patch, atol=1e-7)
    assert both[1].force_vec[2] < 0  # the box pushes the bottom pad down
    assert both[1].image[2].mean() > 0  # both pads see the face pushed in, each in its own frame


def test_a_body_pad_and_a_preset() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    s = TactileSensor(model, data, body="top", pad="digit", normal_axis=(0, 0, -1))
    from tvrecon.sim.sensor.presets import sensor_config

    want = sensor_config("digit", 64)
    assert s.pad.resolution == want.resolution and s.pad.layers == want.layers and s.pad.nu == want.nu
    assert s.pad.pad_size == pytest.approx(0.019 * (max(want.resolution) - 1) / max(want.resolution), rel=1e-6)
    press_by(model, data, 0.001)
    pts = s.contact_points()
    assert pts and all(p.key == 0 and np.allclose(p.normal, (0, 0, 1)) for p in pts)
    assert sum(p.force for p in pts) > 0


def test_geom_meshes() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    assert np.allclose(geom_mesh(model, "box").extents, (0.06, 0.06, 0.02))
    assert np.allclose(geom_mesh(model, "sphere").extents, 0.04, atol=1e-4)
    assert np.allclose(geom_mesh(model, "capsule").extents, (0.02, 0.02, 0.08), atol=1e-4)
    assert np.allclose(geom_mesh(model, "cylinder").extents, (0.03, 0.03, 0.05), atol=1e-4)
    tet = geom_mesh(model, "tet")
    assert isinstance(tet, trimesh.Trimesh) and len(tet.faces) == 4
    assert tet.volume == pytest.approx(0.02**3 / 6, rel=1e-6)  # the asset itself (MuJoCo recentres it)
    floor = geom_mesh(model, "floor")
    assert floor.bounds[1, 2] == pytest.approx(0.0) and floor.extents[0] >= 1.0


def test_clear_errors() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    with pytest.raises(ValueError, match="exactly one"):
        TactileSensor(model, data)
    with pytest.raises(ValueError, match="no geom named"):
        TactileSensor(model, data, geom="nope")
    with pytest.raises(ValueError, match="unknown sensor preset"):
        TactileSensor(model, data, geom="top", pad="nope")
    with pytest.raises(ValueError, match="MjModel"):
        TactileSensor(None, data, geom="top")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="parallel"):
        TactileSensor(model, data, geom="top", normal_axis=(1, 0, 0), up_axis=(1, 0, 0))
