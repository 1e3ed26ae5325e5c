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


def _import_without(hidden: tuple[str, ...], modules: list[str]) -> subprocess.CompletedProcess:
    code = "import sys\n" + "".join(f"sys.modules[{h!r}] = None\n" for h in hidden)
    code += "".join(f"import {m}\n" for m in modules)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "disable")}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


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
