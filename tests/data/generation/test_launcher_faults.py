"""The local launcher works with any ``workers``, and a missing plugin (or its library) is named with its install."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tvrecon.data.generation.launcher import hydra_arguments


@pytest.mark.parametrize("missing", ["joblib", "hydra_plugins.hydra_joblib_launcher"])
def test_a_missing_joblib_launcher_says_how_to_install_it(monkeypatch, missing: str) -> None:
    monkeypatch.setitem(sys.modules, missing, None)  # import of it fails, as when it is not installed
    with pytest.raises(ValueError, match=r"^hydra/launcher=joblib needs Hydra's joblib launcher plugin \(.*\): pip "):
        hydra_arguments(["shard=0/2,1/2", "hydra/launcher=joblib"])


def test_an_installed_launcher_passes_the_check() -> None:
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    assert "hydra/launcher=joblib" in hydra_arguments(["shard=0/2,1/2", "hydra/launcher=joblib"])


@pytest.mark.slow
def test_joblib_launcher_with_the_default_workers_writes_every_entry(tmp_path: Path) -> None:
    """Each job's own pool of spawned workers used to die inside the loky job ("cannot find context for 'loky'"), or
    its initialiser failed to pickle: 0 of 12 entries were written."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    cache = tmp_path / "c"
    cmd = [sys.executable, "-m", "tvrecon.data.generate", "--multirun", "shard=0/2,1/2", "hydra/launcher=joblib"]
    cmd += ["hydra.launcher.n_jobs=2", "preset=tiny", f"cache_dir={cache}", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    done = subprocess.run(cmd, cwd=tmp_path, env={**os.environ, "OMP_NUM_THREADS": "1"}, capture_output=True,
                          text=True, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert len(list(cache.glob("*/*.npz"))) == 12  # tiny: 6 train + 3 val + 3 test items
