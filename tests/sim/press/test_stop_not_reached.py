"""A stop criterion never reached says so (a flag on the reading, a warning, ``--strict`` exits 1).

Before, a ``--force`` (or ``--depth``) the press never reached ended at the travel limit with exit 0 and no word.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from tvrecon.sim.__main__ import main
from tvrecon.sim.press import EIPSimulator, PressConfig
from tvrecon.sim.sensor import SensorConfig

pytestmark = pytest.mark.usefixtures("one_thread")  # see tests/conftest.py

SPHERE = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
SENSOR = SensorConfig(resolution=(8, 8), layers=3)


def test_unreached_force_flags_the_reading_and_warns() -> None:
    sim = EIPSimulator(SENSOR, PressConfig(n_grid=32, force=1e9, max_depth=1.0))
    with pytest.warns(RuntimeWarning, match=r"travel limit .* before its stop criterion \(force 1e\+09\)"):
        reading = sim.press(SPHERE, None, [0.0, 0.0, -1.0])
    assert reading.contact and reading.criterion_missed


def test_reached_depth_is_not_flagged() -> None:
    reading = EIPSimulator(SENSOR, PressConfig(n_grid=32, depth=0.5)).press(SPHERE, None, [0.0, 0.0, -1.0])
    assert reading.contact and not reading.criterion_missed


@pytest.mark.slow
def test_press_cli_strict_exits_1_when_the_force_is_never_reached(tmp_path: Path, capsys) -> None:
    args = ["press", "--shape", "sphere", "--force", "1e9", "--resolution", "8", "--layers", "3", "--n-grid", "32"]
    args += ["--frames", "1", "--ply", "0", "--threads", "1"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0  # without --strict: a warning line, exit 0
    err = capsys.readouterr().err
    assert "warning: the press stopped at its travel limit before --force was reached" in err and "--strict" in err
    assert main([*args, "--strict", "--out", str(tmp_path / "b")]) == 1
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and lines[0].startswith("python -m tvrecon.sim: error: StopNotReached: the press stopped")
    assert (tmp_path / "b" / "reading.npz").is_file()  # the files are still written
