"""An eager press loads neither torch._inductor nor triton, even with ``TORCHINDUCTOR_CACHE_DIR`` set.

The compile policy read torch's default cache folder from ``torch._inductor``, which loads triton: in the MuJoCo
pick-and-place, triton loaded after the EGL context ended the process with SIGSEGV at the first press.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

SCRIPT = textwrap.dedent(
    """
    import sys
    import trimesh
    from tvrecon.sim import EIPSimulator
    from tvrecon.sim.mpm.compiled.policy import compile_cache_dir
    from tvrecon.sim.press.config import PressConfig
    from tvrecon.sim.sensor.elastic_pad import SensorConfig

    sim = EIPSimulator(SensorConfig(resolution=(6, 6), layers=3), PressConfig(n_grid=32, depth=0.5), compile="auto")
    reading = sim.press(trimesh.creation.icosphere(radius=0.5), None, [0.0, 0.0, -1.0])
    print(bool(reading.contact), "torch._inductor" in sys.modules, "triton" in sys.modules, compile_cache_dir())
    """
)


def test_eager_press_with_a_user_compile_cache_loads_no_inductor(tmp_path: Path) -> None:
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "inductor"), "OMP_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["True", "False", "False", str(tmp_path / "inductor")]
