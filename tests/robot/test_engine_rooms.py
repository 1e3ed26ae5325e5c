"""Each physics engine is imported only inside its own room of :mod:`tvrecon.robot`, so either extra works alone.

``pip install -e '.[mujoco]'`` (no pybullet) must import the robot package and the MuJoCo pick-and-place, and
``'.[robot]'`` (no MuJoCo) the pybullet one. A subprocess hides the other engine (``sys.modules[name] = None`` makes
its import raise ImportError, as on a machine without it) and imports the package and the demo.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ROBOT = ROOT / "tvrecon" / "robot"
#: the engine packages and the room of tvrecon.robot that alone may import each
ENGINES = {"pybullet": ("pybullet", "pybullet_data"), "mujoco": ("mujoco",)}


def _run_without(hidden: tuple[str, ...], code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter in which the packages ``hidden`` cannot be imported."""
    code = "import sys\n" + "".join(f"sys.modules[{h!r}] = None\n" for h in hidden) + code
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


def _import_without(hidden: tuple[str, ...], modules: list[str]) -> subprocess.CompletedProcess:
    return _run_without(hidden, "".join(f"import {m}\n" for m in modules))


def test_robot_core_imports_no_engine() -> None:
    result = _import_without(ENGINES["pybullet"] + ENGINES["mujoco"], ["tvrecon.robot", "tvrecon.robot.pad_sensor"])
    assert result.returncode == 0, result.stderr


@pytest.mark.skipif(importlib.util.find_spec("mujoco") is None, reason="needs the mujoco extra")
def test_mujoco_room_without_pybullet() -> None:
    result = _import_without(ENGINES["pybullet"], ["tvrecon.robot", "tvrecon.robot.mujoco.pick_place"])
    assert result.returncode == 0, result.stderr


@pytest.mark.skipif(importlib.util.find_spec("pybullet") is None, reason="needs the robot extra")
def test_pybullet_room_without_mujoco() -> None:
    result = _import_without(ENGINES["mujoco"], ["tvrecon.robot", "tvrecon.robot.pybullet.pick_place"])
    assert result.returncode == 0, result.stderr


_MUJOCO_RUN = """
from tvrecon.robot.mujoco.pick_place import run_mujoco_pick_place
from tvrecon.robot.mujoco.pick_place_config import MujocoPickPlaceConfig
from tvrecon.robot.pad_config import PadConfig

res = run_mujoco_pick_place(MujocoPickPlaceConfig(
    object="cube", out_dir=sys.argv[1], pad=PadConfig(resolution=(12, 12), layers=3, n_grid=40),
    render_size=(96, 72), lift_height=0.06, place_xy=(0.5, 0.0), write_gif=False, write_mp4=False, progress=False,
))
assert res.success, res.message
"""

_PYBULLET_RUN = """
from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pybullet.pick_place import run_pick_place
from tvrecon.robot.pybullet.pick_place_config import PickPlaceConfig

res = run_pick_place(PickPlaceConfig(
    object="can", out_dir=sys.argv[1], render=False, progress=False, frame_every=12,
    pad=PadConfig(resolution=(24, 24), layers=3),
))
assert res.success, res.message
"""


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("mujoco") is None, reason="needs the mujoco extra")
def test_mujoco_pick_place_runs_without_pybullet(tmp_path: Path) -> None:
    result = _run_without(ENGINES["pybullet"], _MUJOCO_RUN.replace("sys.argv[1]", repr(str(tmp_path))))
    assert result.returncode == 0, result.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("pybullet") is None, reason="needs the robot extra")
def test_pybullet_pick_place_runs_without_mujoco(tmp_path: Path) -> None:
    result = _run_without(ENGINES["mujoco"], _PYBULLET_RUN.replace("sys.argv[1]", repr(str(tmp_path))))
    assert result.returncode == 0, result.stderr[-2000:]


def _engine_imports(path: Path) -> set[str]:
    """The engine packages and the other engine rooms of tvrecon.robot a file imports anywhere in it."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module]
        for name in names:
            top = name.split(".")[0]
            for room, packages in ENGINES.items():
                if top in packages or name.startswith(f"tvrecon.robot.{room}"):
                    found.add(room)
    return found


def test_engines_stay_in_their_rooms() -> None:
    """No file outside ``tvrecon/robot/<engine>/`` imports that engine (or that room); the rooms never meet."""
    wrong = []
    for path in sorted(ROBOT.rglob("*.py")):
        room = path.relative_to(ROBOT).parts[0] if len(path.relative_to(ROBOT).parts) > 1 else None
        wrong += [f"{path.relative_to(ROOT)} imports {e}" for e in _engine_imports(path) if e != room]
    assert wrong == []
