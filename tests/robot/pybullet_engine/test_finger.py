"""TactileFinger on a simple pybullet body: contact from the link's contacts, cached EIP presses, rest state."""

import numpy as np
import pybullet as p
import pytest
import trimesh

from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pybullet.finger import TactileFinger

pytest.importorskip("tvrecon.sim.press")


@pytest.fixture()
def world():
    cid = p.connect(p.DIRECT)
    p.setGravity(0, 0, -9.81, physicsClientId=cid)
    half = (0.05, 0.05, 0.02)
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
    block = p.createMultiBody(0.0, col, basePosition=(0, 0, 0.02), physicsClientId=cid)  # static, top at z = 0.04
    fcol = p.createCollisionShape(p.GEOM_BOX, halfExtents=(0.015, 0.015, 0.008), physicsClientId=cid)
    weight = p.createMultiBody(0.5, fcol, basePosition=(0.01, 0.0, 0.0485), physicsClientId=cid)
    for _ in range(240):
        p.stepSimulation(physicsClientId=cid)
    yield cid, block, weight, trimesh.creation.box(extents=[2 * h for h in half])
    p.disconnect(cid)


def test_finger_reads_its_contacts_and_returns_to_rest(world) -> None:
    cid, block, weight, mesh = world
    finger = TactileFinger(
        weight,
        -1,
        normal_axis=(0, 0, -1),
        up_axis=(1, 0, 0),
        pad=PadConfig(resolution=(16, 16)),
        client=cid,
        name="weight",
    )
    finger.attach_object(block, mesh)
    r = finger.sense()
    assert r.contact and r.simulated and r.body == block
    assert r.force == pytest.approx(0.5 * 9.81, rel=0.1)  # it carries its own weight
    assert r.position[2] == pytest.approx(0.04, abs=1e-3) and abs(r.position[0] - 0.01) < 0.01
    assert np.allclose(r.direction, (0, 0, -1), atol=1e-3)
    assert r.image.shape == (3, 16, 16) and r.image.dtype == np.float32
    assert r.image[2].mean() > 0  # the flat face pushes the whole pad in
    assert r.force_vec[2] > 0  # the block pushes the weight up
    again = finger.sense()
    assert not again.simulated and np.array_equal(again.image, r.image)  # cached: nothing changed
    assert finger.sense(refresh=True).simulated
    # lift the weight off: the pad is at rest
    p.resetBasePositionAndOrientation(weight, (0.0, 0.0, 0.2), (0, 0, 0, 1), physicsClientId=cid)
    p.stepSimulation(physicsClientId=cid)
    off = finger.sense()
    assert not off.contact and off.force == 0.0 and not off.image.any()
    assert finger.num_presses == 2


def test_finger_rejects_bad_axes() -> None:
    with pytest.raises(ValueError, match="non-zero"):
        TactileFinger(0, -1, normal_axis=(0, 0, 0))
    with pytest.raises(ValueError, match="parallel"):
        TactileFinger(0, -1, normal_axis=(0, 0, 1), up_axis=(0, 0, 2))
    with pytest.raises(ValueError, match=r"normal_axis must have shape \(3,\), got \(2,\)"):
        TactileFinger(0, -1, normal_axis=(0, 1))
    f = TactileFinger(0, -1, normal_axis=(0, 0, -1), up_axis=(1, 0, 0))
    with pytest.raises(ValueError, match="trimesh"):
        f.attach_object(1, "not a mesh")  # type: ignore[arg-type]
