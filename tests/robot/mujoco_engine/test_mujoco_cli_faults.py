"""The MuJoCo demo's command line: bad input in one line (exit 2), a plan from ground truth said on the result's line,
output under outputs/mujoco_pick_place/<time>/ (printed), no pybullet banner."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

PROG = "python -m tvrecon.robot.mujoco.pick_place"


def _run(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "tvrecon.robot.mujoco.pick_place", *args]
    full_env = {**os.environ, "OMP_NUM_THREADS": "1", **env}
    return subprocess.run(cmd, cwd=cwd, env=full_env, capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize(
    ("args", "env", "message"),
    [
        (["object=can"], {"MUJOCO_GL": "bogus"}, "MUJOCO_GL='bogus' is not a MuJoCo rendering backend: use egl"),
        (["object=can", "place_xy=[0.5]"], {}, "place_xy must hold 2 values (mujoco_pick_place config), got 1: [0.5]"),
    ],
)
def test_bad_input_is_one_line_before_anything_runs(tmp_path: Path, args: list, env: dict, message: str) -> None:
    done = _run(args, tmp_path, **env)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.stderr.strip() == f"{PROG}: error: {message}" or done.stderr.strip().startswith(
        f"{PROG}: error: {message}"
    )
    assert len(done.stderr.strip().splitlines()) == 1


def test_render_false_says_the_grasp_came_from_ground_truth(tmp_path: Path) -> None:
    done = _run(["object=can", "render=false", "progress=false", "write_gif=false", "write_mp4=false"], tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    result = next(ln for ln in done.stdout.splitlines() if ln.startswith("[OK]"))
    assert "[grasp planned from the simulator's own object mesh (ground truth, render=false), not perceived]" in result
    [log] = list((tmp_path / "outputs" / "mujoco_pick_place").glob("*/mujoco_pick_place_log.npz"))
    assert done.stdout.strip().splitlines()[-1] == f"outputs in {log.parent.resolve()}"
    assert "pybullet" not in done.stdout + done.stderr  # no banner of the other engine
