"""A full headless pick-and-place of a can with EIP presses on both fingers (one shared run).

The can is the procedural `can` class (6.5 cm tall), a lathed, faceted solid: its two finger contacts land on
different facets, so the mirrored-pattern check also guards the simulator against facet-dependent artefacts.
"""

import numpy as np
import pytest

from tvrecon.data.shapes import make_shape
from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pick_place_common import PHASES
from tvrecon.robot.pybullet.pick_place import run_pick_place
from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig
from tvrecon.robot.pybullet.scene import SceneConfig

pytest.importorskip("tvrecon.sim.press")

CONTACT_PHASES = [PHASES.index(n) for n in ("squeeze", "lift", "carry", "place")]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pick_place")
    cfg = PickPlaceConfig(
        object="can",
        mesh=make_shape("can", seed=0),
        out_dir=str(out),
        render=False,
        progress=False,
        frame_every=12,
        scene=SceneConfig(),  # the demo default: 6.5 cm longest side
        pad=PadConfig(resolution=(24, 24), layers=3),
    )
    return run_pick_place(cfg)


@pytest.mark.slow
def test_the_grasp_lifts_and_places_the_can(run) -> None:
    assert run.success, run.message
    log = run.log
    z = log["object_pos"][:, 2]
    phase = log["phase"]
    lift_end = np.flatnonzero(phase == PHASES.index("lift"))[-1]
    assert z[lift_end] - z[0] > 0.9 * 0.12  # rose by the lift height
    # while carried the can stays in the gripper: its offset from the grasp point barely changes
    carry = np.flatnonzero(phase == PHASES.index("carry"))
    offset = log["object_pos"][carry] - log["ee_pos"][carry]
    assert np.abs(offset - offset[0]).max() < 0.01
    moved = log["object_pos"][-1, :2] - log["object_pos"][0, :2]
    assert np.linalg.norm(moved) > 0.25  # carried from y = -0.15 to y = +0.15
    assert abs(z[-1] - z[0]) < 0.005  # put back down on the table
    assert run.log_path.exists()


@pytest.mark.slow
def test_tactile_images_follow_contact(run) -> None:
    log = run.log
    tactile, contact, phase = log["tactile"], log["contact"], log["phase"]
    nonzero = np.abs(tactile).reshape(len(tactile), 2, -1).max(-1) > 1e-6  # (K, 2)
    assert np.array_equal(nonzero, contact)  # non-zero exactly when the finger touches
    approach = phase == PHASES.index("approach")
    assert not contact[approach].any()
    held = np.isin(phase, CONTACT_PHASES)
    assert contact[held].all()
    assert (log["force"][held] > 1.0).all()
    # after release the pads are back at rest
    assert not contact[-3:].any() and not tactile[-3:].any()
    # the squeeze indents the pads more than the first touch
    first = np.flatnonzero(contact[:, 0])[0]
    squeezed = np.flatnonzero(phase == PHASES.index("lift"))[-1]
    assert tactile[squeezed, :, 2].max() > tactile[first, :, 2].max()
    assert 0 < run.num_presses <= 40  # presses are cached, not run every frame


@pytest.mark.slow
def test_fingers_see_mirrored_patterns(run) -> None:
    """Mirror-symmetric grasp: the left image equals the right image flipped across the pad's columns."""
    log = run.log
    k = np.flatnonzero(log["phase"] == PHASES.index("lift"))[-1]
    left, right = log["tactile"][k, 0, 2], log["tactile"][k, 1, 2]
    mirrored = np.corrcoef(left.ravel(), np.flip(right, axis=-1).ravel())[0, 1]
    straight = np.corrcoef(left.ravel(), right.ravel())[0, 1]
    assert mirrored > 0.9, mirrored
    assert mirrored > straight + 0.1, (mirrored, straight)
    assert np.allclose(log["force"][k, 0], log["force"][k, 1], rtol=0.2)
    # the pads press in opposite directions
    assert log["direction"][k, 0] @ log["direction"][k, 1] < -0.99
