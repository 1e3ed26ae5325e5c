"""The pybullet scene: object scaling, resting on the table, mesh/body frame agreement, input checks."""

import numpy as np
import pybullet as p
import pytest
import trimesh

from tvrecon.robot.pick_place_common import prepare_object_mesh
from tvrecon.robot.pybullet.scene import PANDA_FINGER_LINKS, Scene, SceneConfig


def test_prepare_object_mesh_scales_and_centres() -> None:
    m = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    m.apply_translation((3.0, -1.0, 2.0))
    out = prepare_object_mesh(m, 0.08)
    assert max(out.extents) == pytest.approx(0.08)
    assert np.allclose(out.center_mass, 0.0, atol=1e-9)
    assert np.allclose(m.bounds[0], (2.0, -1.5, 1.75))  # the input is not modified


def test_prepare_object_mesh_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="trimesh.Trimesh"):
        prepare_object_mesh(np.zeros((3, 3)), 0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="size must be > 0"):
        prepare_object_mesh(trimesh.creation.box(), 0.0)
    with pytest.raises(ValueError, match="empty"):
        prepare_object_mesh(trimesh.Trimesh(), 0.1)


def test_object_rests_on_table_and_mesh_matches_body() -> None:
    can = trimesh.creation.cylinder(radius=0.3, height=1.0, sections=32)
    with Scene(can, SceneConfig(object_size=0.1, object_xy=(0.45, 0.1))) as scene:
        scene.settle(240)  # one second: the object must stay where it was put, resting on the table
        world = scene.object_mesh_world()
        assert world.bounds[0, 2] == pytest.approx(scene.cfg.table_height, abs=2e-3)
        assert np.allclose(world.bounds.mean(axis=0)[:2], (0.45, 0.1), atol=2e-3)
        # the collision shape is where the mesh says: a ray straight down hits the mesh top
        hit = p.rayTest([0.45, 0.1, 1.0], [0.45, 0.1, 0.0], physicsClientId=scene.client)[0]
        assert hit[0] == scene.object
        assert hit[3][2] == pytest.approx(world.bounds[1, 2], abs=2e-3)
        assert 0.02 <= scene.mass <= 0.6
        assert scene.collision_kind == "hull"
        # fingers start open and symmetric
        q = scene.finger_positions()
        assert np.allclose(q, 0.04, atol=1e-3)
        assert len(PANDA_FINGER_LINKS) == 2


@pytest.mark.slow  # pybullet's V-HACD takes ~30 s on a busy 2-core machine
def test_concave_object_gets_convex_decomposition(tmp_path) -> None:
    # a thick ring is far from convex: its hull would fill the hole
    ring = trimesh.creation.annulus(r_min=0.3, r_max=0.5, height=0.3, sections=24)
    with Scene(ring, SceneConfig(object_size=0.08, cache_dir=str(tmp_path), vhacd_resolution=20_000)) as scene:
        assert scene.collision_kind == "vhacd"
        centre = scene.object_pose()[0]
        hit = p.rayTest([centre[0], centre[1], 1.0], [centre[0], centre[1], 0.0], physicsClientId=scene.client)[0]
        assert hit[0] != scene.object  # the ray passes through the hole onto the table
